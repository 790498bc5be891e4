/*
 * virtuose/virtuoseAPI.h - Haption's VirtuoseAPI for applications that
 * include it from a "virtuose" sub-directory (<virtuose/virtuoseAPI.h>):
 * the declarations are those of ../VirtuoseAPI.h.
 */
#include "../VirtuoseAPI.h"
