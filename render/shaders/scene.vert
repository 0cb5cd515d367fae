#version 330 core
// Scene vertices: model coordinates -> world (rotation + offset) -> clip.
// Positions stay camera-relative on the GPU so that float32 keeps millimetres at 100 km.
uniform mat4 u_clip_from_camera_rel;   // projection * view rotation (no translation)
uniform mat3 u_world_from_model;       // body rotation (asteroids); identity for terrain
uniform vec3 u_model_offset;           // model origin in world, relative to the camera
in vec3 in_position;
in vec3 in_normal;
in float in_albedo;                    // per-vertex albedo factor (bodies); see VERTEX_ALBEDO
in float in_scatter;                   // per-vertex scattered irradiance / solar (bodies)
// Specialised at compile time as scene.frag is (VERTEX_ALBEDO: in_albedo is bound;
// VERTEX_SCATTER: in_scatter is; MORPH: the batch geomorphs); the generic program reads
// u_vertex_albedo, u_vertex_scatter and u_morph instead.
#ifndef SPECIALISED
uniform int u_vertex_albedo;           // 1: in_albedo is bound; 0: factor 1
uniform int u_vertex_scatter;          // 1: in_scatter is bound; 0: none
#define VERTEX_ALBEDO u_vertex_albedo
#define VERTEX_SCATTER u_vertex_scatter
#define MORPH 1
#endif
out vec3 v_rel;      // world position minus camera position (m)
out vec3 v_normal;   // world-frame normal (not normalised)
out float v_albedo;  // albedo factor (1 unless the mesh carries one per vertex)
out float v_shadow_bias;  // extra shadow-map bias of coarse geometry (depth units)
out float v_scatter;      // in_scatter where VERTEX_SCATTER is 1, else 0

// Geomorphing (render.terrain_scene and render.asteroid_scene, module docstrings): a vertex
// that the next coarser level of detail lacks slides from its own position to the coarser
// level's surface (in_morph.xyz, normal in_morph_normal) as its distance d from the camera
// grows through the last u_morph_band octave before 2^K, the distance at which the coarser
// level takes over: m = clamp((log2 d - K + band) / band, 0, 1). The factor depends only on
// the vertex's own distance, so a vertex shared by two blocks moves the same in both.
uniform int u_morph;            // 0 off; 1 vertices with in_morph.w == u_morph_level, K =
                                // u_morph_k; 2 every vertex, K = u_morph_k + in_morph.w
uniform float u_morph_level;
uniform float u_morph_k;
uniform float u_morph_band;     // octaves of distance
// terrain shadow bias of coarse geometry: continuous level s = clamp(u_morph_scale d, level,
// u_morph_top), bias = u_bias_per_level * (s < 2 ? 2 (s - 1) : s)
uniform float u_morph_scale;
uniform float u_morph_top;
uniform float u_bias_per_level;
in vec4 in_morph;               // coarser level's position (model frame), key (see u_morph)
in vec3 in_morph_normal;        // coarser level's interpolated normal

void main() {
    vec3 p = in_position;
    vec3 n = in_normal;
    v_shadow_bias = 0.0;
    if (MORPH == 1 && u_morph != 0) {
        float d = length(u_world_from_model * p + u_model_offset);
        float k = u_morph == 1 ? u_morph_k : u_morph_k + in_morph.w;
        if (u_morph == 2 || in_morph.w == u_morph_level) {
            float m = clamp((log2(max(d, 1e-30)) - k + u_morph_band) / u_morph_band, 0.0, 1.0);
            p += m * (in_morph.xyz - p);   // exact where the target is the vertex itself
            n += m * (in_morph_normal - n);
        }
        if (u_bias_per_level > 0.0) {
            float s = clamp(u_morph_scale * d, u_morph_level, u_morph_top);
            v_shadow_bias = u_bias_per_level * (s < 2.0 ? 2.0 * (s - 1.0) : s);
        }
    }
    v_rel = u_world_from_model * p + u_model_offset;
    v_normal = u_world_from_model * n;
    v_albedo = VERTEX_ALBEDO == 1 ? in_albedo : 1.0;
    v_scatter = VERTEX_SCATTER == 1 ? in_scatter : 0.0;
    gl_Position = u_clip_from_camera_rel * vec4(v_rel, 1.0);
}
