/*
 * panel.cpp: the viewer's panel and frame display, the only C++ in nacre (Dear ImGui is C++).
 * It draws the rendered frame as one OpenGL texture filling the window and, over it, a panel
 * whose controls call the same nc_view_* edits as the mouse, the keys and the script
 * (view.h): method, view mode, lights, materials, layered and diffusion settings, fog
 * (volumetrics), particles, timeline, exposure, files, and the current method's stage timings as
 * a bar chart. Which backends and why: panel.h.
 */
#include "panel.h"

#include <SDL_opengl.h>
#include <backends/imgui_impl_opengl2.h>
#include <backends/imgui_impl_sdl.h>
#include <imgui.h>

#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <string.h>
#include <vector>

namespace {

SDL_Window *g_window = nullptr;
GLuint g_texture = 0;
int g_tex_w = 0, g_tex_h = 0;
char g_image_path[256] = "view.png";
char g_scene_path[256] = "view.json";
const char *g_capture = nullptr;

/* The drawn window (before it is presented) as a PNG: OpenGL's rows go bottom up. */
void capture(nc_view *v, int w, int h)
{
    nacre_image img = {};
    if (w <= 0 || h <= 0 || nacre_image_alloc(v->ctx, w, h, 3, &img) != NACRE_OK) {
        snprintf(v->message, sizeof(v->message), "window capture: cannot allocate %dx%d", w, h);
        return;
    }
    std::vector<uint8_t> px((size_t)w * (size_t)h * 3);
    glPixelStorei(GL_PACK_ALIGNMENT, 1);
    glReadBuffer(GL_BACK);
    glReadPixels(0, 0, w, h, GL_RGB, GL_UNSIGNED_BYTE, px.data());
    for (int y = 0; y < h; y++)
        for (size_t i = 0; i < (size_t)w * 3; i++)
            img.pixels[(size_t)y * img.stride + i] = px[(size_t)(h - 1 - y) * (size_t)w * 3 + i] / 255.0f;
    if (nacre_image_write_data(v->ctx, &img, g_capture) != NACRE_OK)
        snprintf(v->message, sizeof(v->message), "%s", nacre_context_last_error(v->ctx));
    nacre_image_free(v->ctx, &img);
}

void upload(const uint8_t *rgba, int w, int h)
{
    if (!g_texture) {
        glGenTextures(1, &g_texture);
        glBindTexture(GL_TEXTURE_2D, g_texture);
    }
    glBindTexture(GL_TEXTURE_2D, g_texture);
    glPixelStorei(GL_UNPACK_ALIGNMENT, 4);
    glPixelStorei(GL_UNPACK_ROW_LENGTH, 0);
    if (w != g_tex_w || h != g_tex_h) {
        glTexImage2D(GL_TEXTURE_2D, 0, GL_RGBA, w, h, 0, GL_RGBA, GL_UNSIGNED_BYTE, rgba);
        g_tex_w = w;
        g_tex_h = h;
    } else {
        glTexSubImage2D(GL_TEXTURE_2D, 0, 0, 0, w, h, GL_RGBA, GL_UNSIGNED_BYTE, rgba);
    }
}

/* The frame over the whole window, opaque, before the panel. Drawn here rather than as an ImGui
 * image because ImGui blends everything it draws, and with Mesa's software rasterizer a blended,
 * filtered full-window quad after a clear cost several ms a frame; one texel per pixel (nearest)
 * while the window has the frame's size. */
void draw_frame(bool one_to_one)
{
    GLint filter = one_to_one ? GL_NEAREST : GL_LINEAR;
    glBindTexture(GL_TEXTURE_2D, g_texture);
    glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_MIN_FILTER, filter);
    glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_MAG_FILTER, filter);
    glDisable(GL_BLEND);
    glDisable(GL_SCISSOR_TEST);
    glDisable(GL_DEPTH_TEST);
    glDisable(GL_LIGHTING);
    glEnable(GL_TEXTURE_2D);
    glTexEnvi(GL_TEXTURE_ENV, GL_TEXTURE_ENV_MODE, GL_REPLACE);
    glMatrixMode(GL_PROJECTION);
    glLoadIdentity();
    glMatrixMode(GL_MODELVIEW);
    glLoadIdentity();
    glBegin(GL_QUADS); /* texture row 0 is the frame's top row */
    glTexCoord2f(0, 1);
    glVertex2f(-1, -1);
    glTexCoord2f(1, 1);
    glVertex2f(1, -1);
    glTexCoord2f(1, 0);
    glVertex2f(1, 1);
    glTexCoord2f(0, 0);
    glVertex2f(-1, 1);
    glEnd();
    glDisable(GL_TEXTURE_2D);
}

/* The current method's stages as horizontal bars (ms), like the seed's tables 5.1-5.3: a bar
 * per stage the method has, coloured when the stage ran this frame, grey when it was cached. */
void stage_chart(const nc_view *v)
{
    nacre_method_info info;
    nacre_method_info_get(v->fs.render.method, &info);
    uint64_t most = 1;
    for (int i = 0; i < NACRE_STAGE_COUNT; i++)
        if (v->stats.stage_us[i] > most)
            most = v->stats.stage_us[i];
    if (info.stochastic) {
        ImGui::Text("path tracer: %u spp accumulated, %.3g Msamples/s", v->stats.spp_done,
                    v->stats.samples_per_second * 1e-6);
        return;
    }
    for (int i = 0; i < NACRE_STAGE_COUNT; i++) {
        /* The method's own stages always (cached ones in grey); the passes over its image (fog,
         * froxel_*, raymarch, particles) run by the scene and the settings rather than the
         * method, so they show when they ran. */
        if (!(info.stages & (1u << i)) && !v->stats.stage_ran[i])
            continue;
        char label[64];
        bool ran = v->stats.stage_ran[i];
        snprintf(label, sizeof(label), ran ? "%.2f ms x%u" : "cached", v->stats.stage_us[i] * 1e-3,
                 v->stats.stage_runs[i]);
        ImGui::Text("%-16s", nacre_stage_name((nacre_stage)i));
        ImGui::SameLine(136);
        ImGui::PushStyleColor(ImGuiCol_PlotHistogram, ran ? ImVec4(0.9f, 0.6f, 0.1f, 1) : ImVec4(0.4f, 0.4f, 0.4f, 1));
        ImGui::ProgressBar(ran ? (float)v->stats.stage_us[i] / (float)most : 0.0f, ImVec2(-1, 0), label);
        ImGui::PopStyleColor();
    }
    ImGui::Text("frame %.2f ms", v->stats.total_us * 1e-3);
}

void method_controls(nc_view *v)
{
    const char *current = nacre_method_name(v->fs.render.method);
    if (ImGui::BeginCombo("method", current)) {
        for (int m = 0; m < NACRE_METHOD_COUNT; m++) {
            bool available = nacre_method_available((nacre_method)m);
            char label[64];
            snprintf(label, sizeof(label), "%s%s", nacre_method_name((nacre_method)m),
                     available ? "" : " (not implemented)");
            if (!available)
                ImGui::BeginDisabled();
            if (ImGui::Selectable(label, m == (int)v->fs.render.method))
                nc_view_set_method(v, (nacre_method)m, false);
            if (!available)
                ImGui::EndDisabled();
        }
        ImGui::EndCombo();
    }
    int mode = (int)v->mode;
    ImGui::RadioButton("frame", &mode, NC_VIEW_NORMAL);
    ImGui::SameLine();
    ImGui::RadioButton("wipe (t)", &mode, NC_VIEW_WIPE);
    ImGui::SameLine();
    ImGui::RadioButton("error (e)", &mode, NC_VIEW_ERROR);
    if (mode != (int)v->mode)
        nc_view_set_mode(v, (nc_view_mode)mode);
    if (v->mode == NC_VIEW_WIPE)
        ImGui::SliderFloat("wipe", &v->wipe, 0.0f, 1.0f);
    if (v->mode != NC_VIEW_NORMAL) {
        ImGui::Text("path tracer: %u spp", v->truth_stats.spp_done);
        if (v->mean_rel_err >= 0)
            ImGui::Text("mean relative error %.2f %%", 100.0 * v->mean_rel_err);
    }
    if (ImGui::SliderFloat("exposure", &v->fs.exposure, -4.0f, 4.0f, "%.2f EV"))
        v->need_render = true;
}

void light_controls(nc_view *v)
{
    uint32_t n = nacre_scene_light_count(v->scene);
    if (n == 0 || !ImGui::CollapsingHeader("light", ImGuiTreeNodeFlags_DefaultOpen))
        return;
    int sel = (int)v->light;
    if (ImGui::SliderInt("light ([ ])", &sel, 0, (int)n - 1))
        v->light = (uint32_t)sel;
    nacre_light_desc d;
    if (nacre_scene_get_light(v->scene, nacre_light{v->light + 1}, &d) != NACRE_OK)
        return;
    if (d.type != NACRE_LIGHT_POINT && ImGui::SliderFloat3("direction", d.direction, -1.0f, 1.0f))
        nc_view_light_direction(v, v->light, d.direction, false);
    if (d.type != NACRE_LIGHT_DIRECTIONAL && ImGui::DragFloat3("position", d.position, 1.0f))
        nc_view_light_position(v, v->light, d.position, false);
    if (ImGui::DragFloat3("strength", d.strength, 0.05f, 0.0f, 1e6f))
        nc_view_light_strength(v, v->light, d.strength, false);
    ImGui::TextDisabled("arrow keys turn the light");
}

void material_controls(nc_view *v)
{
    if (v->material_count == 0 || !ImGui::CollapsingHeader("material", ImGuiTreeNodeFlags_DefaultOpen))
        return;
    int sel = (int)v->material;
    if (ImGui::SliderInt("material", &sel, 0, (int)v->material_count - 1))
        v->material = (uint32_t)sel;
    nc_view_material *m = &v->materials[v->material];
    const char *shown = m->preset >= 0 ? nc_view_presets[m->preset]
                        : m->base.type == NACRE_MATERIAL_OPAQUE ? "(opaque, as loaded)" : "(as loaded)";
    if (ImGui::BeginCombo("preset", shown)) {
        for (int i = 0; nc_view_presets[i]; i++)
            if (ImGui::Selectable(nc_view_presets[i], i == m->preset))
                nc_view_material_preset(v, v->material, nc_view_presets[i], false);
        ImGui::EndCombo();
    }
    if (m->base.type != NACRE_MATERIAL_TRANSLUCENT)
        return;
    float x = m->sigma_a_scale;
    if (ImGui::SliderFloat("sigma_a x", &x, 0.01f, 100.0f, "%.3g", ImGuiSliderFlags_Logarithmic))
        nc_view_material_field(v, v->material, "sigma_a_scale", x, false);
    x = m->sigma_s_scale;
    if (ImGui::SliderFloat("sigma_s x", &x, 0.01f, 100.0f, "%.3g", ImGuiSliderFlags_Logarithmic))
        nc_view_material_field(v, v->material, "sigma_s_scale", x, false);
    x = m->base.g;
    if (ImGui::SliderFloat("g", &x, -0.95f, 0.95f))
        nc_view_material_field(v, v->material, "g", x, false);
    x = m->base.eta;
    if (ImGui::SliderFloat("eta", &x, 1.0f, 2.5f))
        nc_view_material_field(v, v->material, "eta", x, false);
    if (m->base.layering.count > 0) {
        bool ms = m->base.layering.multiple_scattering == NACRE_MULTIPLE_SCATTERING_DIFFUSION;
        if (ImGui::Checkbox("multiple scattering (diffusion)", &ms))
            nc_view_material_field(v, v->material, "multiple_scattering", ms ? 1.0f : 0.0f, false);
    }
    /* Layer depths (seed 001's layer thicknesses; with a depth map, the scale of its channel):
     * the slider spans 0 to 4x the deepest loaded layer, so a preset's range stays usable. */
    float deepest = 0.0f;
    for (uint32_t k = 0; k < m->base.layering.count; k++)
        deepest = fmaxf(deepest, m->layer_depth_loaded[k]);
    for (uint32_t k = 0; k < m->base.layering.count; k++) {
        char label[32], field[32];
        snprintf(label, sizeof(label), "layer %u depth", k);
        snprintf(field, sizeof(field), "layer%u_depth", k);
        x = m->base.layering.layers[k].depth;
        if (ImGui::SliderFloat(label, &x, 0.0f, deepest > 0.0f ? 4.0f * deepest : 1.0f, "%.3g"))
            nc_view_material_field(v, v->material, field, x, false);
    }
}

/* An integer render setting through nc_view_render_setting, applied when the slider is
 * released: each step of a drag would otherwise rebuild the stage's buffers. */
void setting_slider(nc_view *v, const char *label, const char *name, uint32_t current, int lo, int hi)
{
    int x = (int)current;
    ImGui::SliderInt(label, &x, lo, hi, "%d", ImGuiSliderFlags_Logarithmic);
    if ((ImGui::IsItemDeactivatedAfterEdit() || !ImGui::IsItemActive()) && x != (int)current) {
        char text[16];
        snprintf(text, sizeof(text), "%d", x);
        nc_view_render_setting(v, name, text, false);
    }
}

/* A choice among names (radio buttons) through nc_view_render_setting. */
void setting_choice(nc_view *v, const char *name, const char *const *choices, const char *current)
{
    for (int i = 0; choices[i]; i++) {
        if (i)
            ImGui::SameLine();
        char label[64];
        snprintf(label, sizeof(label), "%s##%s", choices[i], name);
        if (ImGui::RadioButton(label, strcmp(choices[i], current) == 0) && strcmp(choices[i], current) != 0)
            nc_view_render_setting(v, name, choices[i], false);
    }
}

void layered_controls(nc_view *v)
{
    if (v->fs.render.method != NACRE_METHOD_LAYERED ||
        !ImGui::CollapsingHeader("layered", ImGuiTreeNodeFlags_DefaultOpen))
        return;
    nacre_layered_settings *ly = &v->fs.render.layered;
    setting_slider(v, "samples", "layered_samples", ly->samples, 1, 256);
    static const char *const integrations[] = {"analytic", "samples", nullptr};
    ImGui::Text("integration");
    ImGui::SameLine();
    setting_choice(v, "layered_integration", integrations, nacre_layered_integration_name(ly->integration));
    float e = ly->epsilon;
    ImGui::SliderFloat("epsilon", &e, 0.001f, 0.5f, "%.4f", ImGuiSliderFlags_Logarithmic);
    /* On release: epsilon refits the planes (stage planes). */
    if ((ImGui::IsItemDeactivatedAfterEdit() || !ImGui::IsItemActive()) && e != ly->epsilon) {
        char text[32];
        snprintf(text, sizeof(text), "%.9g", e);
        nc_view_render_setting(v, "layered_epsilon", text, false);
    }
}

void media_controls(nc_view *v)
{
    nacre_method_info info;
    nacre_method_info_get(v->fs.render.method, &info);
    if (nacre_scene_fog_count(v->scene) > 0 && ImGui::CollapsingHeader("fog", ImGuiTreeNodeFlags_DefaultOpen)) {
        nacre_volumetrics_settings *vol = &v->fs.render.volumetrics;
        static const char *const modes[] = {"off", "froxel", "raymarch", nullptr};
        setting_choice(v, "volumetrics", modes, nacre_volumetrics_name(vol->mode));
        if (vol->mode == NACRE_VOLUMETRICS_FROXEL) {
            setting_slider(v, "froxels x", "froxel_width", vol->froxel_width, 8, 1024);
            setting_slider(v, "froxels y", "froxel_height", vol->froxel_height, 8, 1024);
            setting_slider(v, "slices", "froxel_slices", vol->froxel_slices, 8, 1024);
        } else if (vol->mode == NACRE_VOLUMETRICS_RAYMARCH) {
            setting_slider(v, "steps", "raymarch_steps", vol->raymarch_steps, 1, 4096);
        }
        if (vol->mode != NACRE_VOLUMETRICS_OFF)
            setting_slider(v, "shadow steps", "shadow_steps", vol->shadow_steps, 1, 256);
        if (info.renders_fog)
            ImGui::TextDisabled("the path tracer renders the fog itself");
    }
    if (nacre_scene_particles_count(v->scene) > 0 &&
        ImGui::CollapsingHeader("particles", ImGuiTreeNodeFlags_DefaultOpen)) {
        static const char *const draws[] = {"billboards", "sprites", "voxel", nullptr};
        setting_choice(v, "particles", draws, nacre_particles_draw_name(v->fs.render.particles));
        ImGui::TextDisabled("the timeline's time moves them");
    }
}

void settings_controls(nc_view *v)
{
    if (ImGui::CollapsingHeader("diffusion")) {
        int res = (int)v->fs.render.diffusion.voxel_resolution;
        /* On release only: every step would re-voxelize. */
        ImGui::SliderInt("voxels", &res, 8, 128);
        if (ImGui::IsItemDeactivatedAfterEdit())
            nc_view_voxel_resolution(v, (uint32_t)res, false);
        else if (!ImGui::IsItemActive() && res != (int)v->fs.render.diffusion.voxel_resolution)
            nc_view_voxel_resolution(v, (uint32_t)res, false);
        int solver = (int)v->fs.render.diffusion.solver;
        ImGui::RadioButton("multigrid", &solver, NACRE_SOLVER_MULTIGRID);
        ImGui::SameLine();
        ImGui::RadioButton("seed (Jacobi)", &solver, NACRE_SOLVER_SEED);
        nc_view_solver(v, (nacre_diffusion_solver)solver);
        /* The per-pixel first order (single.c); auto: on for patterned media. */
        int single = (int)v->fs.render.diffusion.single_scattering;
        ImGui::Text("single scattering");
        ImGui::SameLine();
        ImGui::RadioButton("auto", &single, NACRE_SINGLE_SCATTERING_AUTO);
        ImGui::SameLine();
        ImGui::RadioButton("on", &single, NACRE_SINGLE_SCATTERING_ON);
        ImGui::SameLine();
        ImGui::RadioButton("off", &single, NACRE_SINGLE_SCATTERING_OFF);
        if (single != (int)v->fs.render.diffusion.single_scattering)
            nc_view_render_setting(v, "single_scattering", nacre_single_scattering_name((nacre_single_scattering)single),
                                   false);
    }
    if (ImGui::CollapsingHeader("timeline", ImGuiTreeNodeFlags_DefaultOpen)) {
        if (ImGui::Button(v->playing ? "pause (p)" : "play (p)"))
            v->playing = !v->playing;
        ImGui::SameLine();
        float t = (float)v->fs.time;
        if (ImGui::SliderFloat("time", &t, 0.0f, (float)v->time_max, "%.2f s"))
            nc_view_set_time(v, t);
    }
    if (ImGui::CollapsingHeader("file")) {
        ImGui::InputText("image", g_image_path, sizeof(g_image_path));
        if (ImGui::Button("Save image (.png, .exr)"))
            nc_view_save_image(v, g_image_path);
        ImGui::InputText("scene", g_scene_path, sizeof(g_scene_path));
        if (ImGui::Button("Save scene (.json)"))
            nc_view_save_scene(v, g_scene_path);
    }
}

} // namespace

extern "C" bool nc_panel_init(SDL_Window *window, void *gl_context, char *err, size_t err_size)
{
    IMGUI_CHECKVERSION();
    ImGui::CreateContext();
    ImGui::GetIO().IniFilename = nullptr; /* no imgui.ini in the working directory */
    ImGui::StyleColorsDark();
    if (!ImGui_ImplSDL2_InitForOpenGL(window, gl_context) || !ImGui_ImplOpenGL2_Init()) {
        snprintf(err, err_size, "cannot set up the panel (Dear ImGui's SDL2 + OpenGL 2 backends)");
        return false;
    }
    g_window = window;
    return true;
}

extern "C" void nc_panel_shutdown(void)
{
    if (!g_window)
        return;
    if (g_texture)
        glDeleteTextures(1, &g_texture);
    g_texture = 0;
    g_tex_w = g_tex_h = 0;
    ImGui_ImplOpenGL2_Shutdown();
    ImGui_ImplSDL2_Shutdown();
    ImGui::DestroyContext();
    g_window = nullptr;
}

extern "C" bool nc_panel_event(const SDL_Event *event)
{
    ImGui_ImplSDL2_ProcessEvent(event);
    ImGuiIO &io = ImGui::GetIO();
    switch (event->type) {
    case SDL_MOUSEBUTTONDOWN:
    case SDL_MOUSEBUTTONUP:
    case SDL_MOUSEMOTION:
    case SDL_MOUSEWHEEL:
        return io.WantCaptureMouse;
    case SDL_KEYDOWN:
    case SDL_KEYUP:
    case SDL_TEXTINPUT:
        return io.WantCaptureKeyboard;
    default:
        return false;
    }
}

namespace {

/* The lights' handles over the frame: a ring per light, filled for the selected one; a
 * directional light's handle has a line to the camera target, the pivot it swings about. */
void light_handles(nc_view *v, int width, int height)
{
    ImGuiIO &io = ImGui::GetIO();
    ImDrawList *dl = ImGui::GetBackgroundDrawList();
    const float sx = io.DisplaySize.x / (float)(width > 0 ? width : 1), sy = io.DisplaySize.y / (float)(height > 0 ? height : 1);
    const uint32_t n = nacre_scene_light_count(v->scene);
    for (uint32_t i = 0; i < n; i++) {
        float x, y;
        if (!nc_view_light_handle_pixel(v, i, &x, &y))
            continue;
        ImVec2 c(x * sx, y * sy);
        const ImU32 colour = i == v->light ? IM_COL32(255, 210, 60, 255) : IM_COL32(230, 230, 230, 200);
        nacre_light_desc d;
        if (nacre_scene_get_light(v->scene, nacre_light{i + 1}, &d) == NACRE_OK && d.type == NACRE_LIGHT_DIRECTIONAL) {
            /* The camera looks at the target: it is the frame's centre. */
            dl->AddLine(c, ImVec2(0.5f * io.DisplaySize.x, 0.5f * io.DisplaySize.y), colour, 1.0f);
        }
        if (i == v->light)
            dl->AddCircleFilled(c, NC_VIEW_HANDLE_PX * 0.6f * sx, colour);
        dl->AddCircle(c, NC_VIEW_HANDLE_PX * sx, colour, 0, 2.0f);
    }
}

} // namespace

extern "C" void nc_panel_draw(nc_view *v, const uint8_t *rgba, int width, int height, bool show_panel)
{
    upload(rgba, width, height);
    ImGui_ImplOpenGL2_NewFrame();
    ImGui_ImplSDL2_NewFrame();
    ImGui::NewFrame();
    light_handles(v, width, height);
    if (show_panel) {
        ImGui::SetNextWindowPos(ImVec2(8, 8), ImGuiCond_FirstUseEver);
        ImGui::SetNextWindowSize(ImVec2(330, 0), ImGuiCond_FirstUseEver);
        ImGui::SetNextWindowBgAlpha(0.85f);
        ImGui::Begin("nacre view (h hides)");
        ImGui::Text("%.1f fps  %dx%d  t %.2f s", v->fps, width, height, v->fs.time);
        method_controls(v);
        if (ImGui::CollapsingHeader("stages", ImGuiTreeNodeFlags_DefaultOpen))
            stage_chart(v);
        light_controls(v);
        material_controls(v);
        layered_controls(v);
        media_controls(v);
        settings_controls(v);
        if (v->object != UINT32_MAX)
            ImGui::Text("selected object %u", v->object);
        if (v->message[0])
            ImGui::TextWrapped("%s", v->message);
        ImGui::End();
    }
    ImGui::Render();
    int dw = 0, dh = 0;
    SDL_GL_GetDrawableSize(g_window, &dw, &dh);
    glViewport(0, 0, dw, dh);
    draw_frame(dw == width && dh == height);
    ImGui_ImplOpenGL2_RenderDrawData(ImGui::GetDrawData());
    if (g_capture) {
        capture(v, dw, dh);
        g_capture = nullptr;
    }
    SDL_GL_SwapWindow(g_window);
}

extern "C" void nc_panel_capture(const char *path) { g_capture = path; }
