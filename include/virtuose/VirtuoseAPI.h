/*
 * virtuose/VirtuoseAPI.h - Haption's VirtuoseAPI for applications that
 * include it from a "virtuose" sub-directory (<virtuose/VirtuoseAPI.h>):
 * the declarations are those of ../VirtuoseAPI.h.
 */
#include "../VirtuoseAPI.h"
