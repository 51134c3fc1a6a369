/*
 * view_stub.c: `nacre view` in a build without SDL2 or Dear ImGui (CMake found neither
 * libsdl2-dev nor libimgui-dev, or NACRE_VIEWER=OFF): one line saying so, exit status 2.
 */
#include "cli.h"

#include <string.h>

int nc_cli_view(int argc, char **argv)
{
    int code;
    for (int i = 0; i < argc; i++)
        if (nc_tool_common_flag("view", argv[i], "usage: nacre view [SCENE.json] [options]\n"
                                                 "This nacre was built without the viewer (SDL2, Dear ImGui).\n",
                                &code))
            return code;
    return nc_tool_error("view: this nacre was built without SDL2 and Dear ImGui: install libsdl2-dev, "
                         "libimgui-dev and libgl-dev (scripts/install-deps.sh) and rebuild");
}
