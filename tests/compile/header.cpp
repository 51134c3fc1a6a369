#include <nacre/nacre.h>
int nacre_header_compiles_as_cxx();
int nacre_header_compiles_as_cxx() { return NACRE_OK; }
