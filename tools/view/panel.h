/*
 * panel.h: the C interface of panel.cpp, the viewer's only C++: Dear ImGui (Debian's libimgui-dev
 * 1.86) with its SDL2 platform backend and its OpenGL 2 renderer backend. Debian's package ships
 * the header of the SDL_Renderer backend but not its code (libimgui.a has no
 * imgui_impl_sdlrenderer.o: linking ImGui_ImplSDLRenderer_Init fails), so the frame and the panel
 * are drawn with the package's OpenGL 2 backend, through Mesa under Xvfb (README, `nacre view`).
 */
#ifndef NACRE_VIEW_PANEL_H
#define NACRE_VIEW_PANEL_H

#include "view.h"

#include <SDL.h>

#ifdef __cplusplus
extern "C" {
#endif

/* After the GL context of `window` is current; false with SDL's or GL's reason in err. */
bool nc_panel_init(SDL_Window *window, void *gl_context, char *err, size_t err_size);
void nc_panel_shutdown(void);
/* Give an event to the panel; true if the panel takes it (the mouse is over it, a field has
 * the keyboard), so the viewer must not also orbit or press keys. */
bool nc_panel_event(const SDL_Event *event);
/* Upload the frame (RGBA bytes, width x height) and draw it filling the window, then the panel
 * (unless hidden), then present. */
void nc_panel_draw(nc_view *v, const uint8_t *rgba, int width, int height, bool show_panel);
/* Write the window as the next nc_panel_draw leaves it (frame, light handles and panel) to a PNG
 * at `path`; the result goes to v->message when that draw fails to write it. NULL: nothing. */
void nc_panel_capture(const char *path);

#ifdef __cplusplus
}
#endif

#endif /* NACRE_VIEW_PANEL_H */
