#include <nacre/nacre.h>
int nacre_header_compiles_as_c(void);
int nacre_header_compiles_as_c(void) { return NACRE_OK; }
