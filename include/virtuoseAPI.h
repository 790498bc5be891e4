/*
 * virtuoseAPI.h - Haption's VirtuoseAPI under the lower-case name many
 * applications include ("virtuoseAPI.h"): the declarations are those of
 * VirtuoseAPI.h.
 */
#include "VirtuoseAPI.h"
