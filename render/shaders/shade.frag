#version 330 core
#extension GL_ARB_texture_gather : require
// The shading pass: radiance and range from what the surface pass (scene.frag) left in each
// pixel.
//
// Deferred shading: the surface pass draws every batch and keeps, per pixel, the nearest
// fragment's position and normal (and a body's per-vertex values), and in the stencil the
// group of batches it belongs to (those that share a shadow map and maps); this pass shades
// each pixel once, one full-screen triangle per group, drawn where the stencil holds the
// group. A CPU rasteriser runs the fragment shader on a 4x4 block per triangle that touches
// it, so with triangles of a pixel or two a forward pass shaded each pixel many times over;
// it skips a block whose pixels all fail the stencil test before any shading. The
// arithmetic is the forward shading's on the same float32 values, so the radiance is the
// same bytes.
//
// Specialised at compile time as scene.frag is (the renderer prepends a #define for each
// switch below); without them, each switch is read from its uniform.
#ifndef SPECIALISED
uniform int u_brdf;             // 0 Lambert, 1 Lommel-Seeliger, 2 lunar-Lambert (McEwen), 3 Hapke
uniform int u_vertex_albedo;    // 1: the surface pass's albedo factor scales the albedo
uniform int u_use_albedo_map;   // 1: u_albedo_map scales the albedo (or w) by its value
uniform int u_scatter_map;      // 1: u_scatter holds light scattered from the terrain
uniform int u_vertex_scatter;   // 1: the surface pass's scattered light (bodies), not the map
uniform int u_shadows;
uniform int u_soft_shadows;     // 1: the sun is its disk (u_sun_tan)
uniform int u_scattering;       // 1: add r (Lambertian, the surface's albedo)
uniform int u_earthshine_on;    // 1: add the Earth's light (u_earthshine)
#define BRDF u_brdf
#define VERTEX_ALBEDO u_vertex_albedo
#define ALBEDO_MAP u_use_albedo_map
#define SCATTER_MAP u_scatter_map
#define VERTEX_SCATTER u_vertex_scatter
#define SHADOWS u_shadows
#define SOFT_SHADOWS u_soft_shadows
#define SCATTERING u_scattering
#define EARTHSHINE u_earthshine_on
#endif
uniform sampler2D u_surface_normal;  // the surface pass's images: normal (xyz, 1 where hit),
uniform sampler2D u_surface_rel;     // camera-relative position (m) and extra shadow bias,
uniform sampler2D u_surface_vertex;  // per-vertex albedo factor and scattered light (bodies)
uniform vec3 u_camera;          // camera position in world (m)
uniform sampler2D u_albedo_map;
uniform vec4 u_albedo_window;   // xmin, ymin, xmax, ymax (scene-local) the map's texels span

uniform vec3 u_sun;             // unit vector towards the sun (world)
uniform float u_albedo;
uniform vec3 u_mcewen;          // lunar-Lambert L(g) = 1 + a g + b g^2 + c g^3, g in degrees
uniform vec4 u_hapke_a;         // Hapke: w, b, c, Bs0
uniform vec4 u_hapke_b;         // Hapke: hs, Bc0, hc, theta-bar (radians)
uniform float u_hapke_k;        // Hapke porosity factor K (1: none)

uniform sampler2DShadow u_shadow_map;  // the map, compared <= with 2x2 bilinear filtering
uniform sampler2D u_shadow_depth;      // the same map, its raw depths (blocker search)
uniform mat4 u_light_from_world;  // world (camera-relative) -> shadow texture [0,1]^3
uniform mat3 u_light_axes;        // world -> light-space axes (x, y, direction light travels)
uniform vec2 u_texel;             // m: a texel's side along light-space x and y
uniform vec2 u_shadow_extent;     // m: the map's side along light-space x and y
uniform float u_depth_range;      // m: the depth the map spans
uniform float u_normal_offset;    // m, along the normal before the lookup
uniform float u_bias;             // depth units, constant
uniform float u_slope_texels;     // texels of depth per unit of the receiver's depth gradient
uniform float u_sun_tan;          // tangent of the solar disk's angular radius (0: a point)

uniform sampler2D u_scatter;      // r: scattered irradiance / solar irradiance; g: Earth seen
uniform vec4 u_scatter_rect;      // (x0, y0, 1/width, 1/height), scene-local x, y to texture
uniform vec3 u_earth;             // unit vector towards the Earth (world)
uniform float u_earthshine;       // Earth's irradiance / the Sun's (0: none)

layout(location = 0) out float out_radiance;
layout(location = 1) out float out_range;   // the LIDAR range (m)

float reflectance(float mu0, float mu, float g_deg, float scale) {
    if (mu0 <= 0.0) return 0.0;
    mu = max(mu, 1e-4);
    float albedo = u_albedo * scale;
    if (BRDF == 0) return albedo * mu0;                              // Lambert: A mu0
    float ls = 2.0 * mu0 / (mu0 + mu);                                 // 1 at mu0 = mu = 1
    if (BRDF == 1) return albedo * ls;                               // Lommel-Seeliger
    float L = 1.0 + g_deg * (u_mcewen.x + g_deg * (u_mcewen.y + g_deg * u_mcewen.z));
    return albedo * (L * ls + (1.0 - L) * mu0);                        // McEwen (1991)
}

// ---- Hapke (2012, Theory of Reflectance and Emittance Spectroscopy, 2nd ed.), the form Sato et
// al. (2014, JGR Planets 119, 1775) fit to LROC WAC: I/F = K w/4 mu0e/(mu0e + mue)
// [p(g)(1 + Bs0 Bs(g)) + M(mu0e/K, mue/K)] [1 + Bc0 Bc(g)] S(i, e, psi). Angles come from
// vectors (tan(g/2) and psi by atan/cross products), which keeps float32 accurate near g = 0.
float hapke_h(float x, float w) {                  // Hapke (2002) eq. 13
    float gam = sqrt(1.0 - w);
    float r0 = (1.0 - gam) / (1.0 + gam);
    x = max(x, 1e-6);
    return 1.0 / (1.0 - w * x * (r0 + 0.5 * (1.0 - 2.0 * r0 * x) * log((1.0 + x) / x)));
}

float hapke_e1(float cot_t, float cot_x) { return exp(-0.63661977 * cot_t * cot_x); }
float hapke_e2(float cot_t, float cot_x) { return exp(-0.31830989 * cot_t * cot_t * cot_x * cot_x); }

float hapke(vec3 n, vec3 s, vec3 v, float scale) {
    float mu0 = dot(n, s);
    if (mu0 <= 0.0) return 0.0;
    float mu = max(dot(n, v), 1e-4);
    float w = min(u_hapke_a.x * scale, 0.999999);
    float b = u_hapke_a.y;
    float c = u_hapke_a.z;
    float cg = dot(s, v);
    float tg2 = length(cross(s, v)) / max(1.0 + cg, 1e-12);             // tan(g/2)
    float b2 = b * b;
    float p = 0.5 * (1.0 + c) * (1.0 - b2) / pow(1.0 - 2.0 * b * cg + b2, 1.5)
            + 0.5 * (1.0 - c) * (1.0 - b2) / pow(1.0 + 2.0 * b * cg + b2, 1.5);
    float bs = u_hapke_b.x > 0.0 ? 1.0 / (1.0 + tg2 / u_hapke_b.x) : 0.0;
    float bc = 0.0;
    if (u_hapke_b.y > 0.0 && u_hapke_b.z > 0.0) {                     // Hapke (2002) eq. 31
        float x = tg2 / u_hapke_b.z;
        bc = x < 1e-4 ? 1.0 - 1.5 * x : (1.0 + (1.0 - exp(-x)) / x) / (2.0 * (1.0 + x) * (1.0 + x));
    }
    float mu0e = mu0;
    float mue = mu;
    float sh = 1.0;
    float theta = u_hapke_b.w;
    if (theta > 1e-6) {                     // Hapke (1984), 2012 ch. 12; ROUGH_MIN in Python
        float tt = tan(theta);
        float cot_t = 1.0 / tt;
        float chi = inversesqrt(1.0 + 3.14159265 * tt * tt);
        vec3 st = s - mu0 * n;
        vec3 vt = v - dot(n, v) * n;
        float si = length(st);
        float se = length(vt);
        float psi = (si * se > 1e-7) ? atan(length(cross(st, vt)), dot(st, vt)) : 0.0;
        float f = psi < 3.1415 ? exp(-2.0 * tan(0.5 * psi)) : 0.0;
        float s2 = sin(0.5 * psi);
        s2 *= s2;
        float cot_i = min(mu0 / max(si, 1e-10), 1e6);
        float cot_e = min(mu / max(se, 1e-10), 1e6);
        float e1i = hapke_e1(cot_t, cot_i), e2i = hapke_e2(cot_t, cot_i);
        float e1e = hapke_e1(cot_t, cot_e), e2e = hapke_e2(cot_t, cot_e);
        float eta_i = chi * (mu0 + si * tt * e2i / (2.0 - e1i));
        float eta_e = chi * (mu + se * tt * e2e / (2.0 - e1e));
        float q;
        if (mu0 >= mu) {                                               // i <= e
            float d = 2.0 - e1e - psi / 3.14159265 * e1i;
            mu0e = chi * (mu0 + si * tt * (cos(psi) * e2e + s2 * e2i) / d);
            mue = chi * (mu + se * tt * (e2e - s2 * e2i) / d);
            q = mu0 / eta_i;
        } else {
            float d = 2.0 - e1i - psi / 3.14159265 * e1e;
            mu0e = chi * (mu0 + si * tt * (e2i - s2 * e2e) / d);
            mue = chi * (mu + se * tt * (cos(psi) * e2i + s2 * e2e) / d);
            q = mu / eta_e;
        }
        sh = mue / eta_e * mu0 / eta_i * chi / (1.0 - f + f * chi * q);
    }
    float k = u_hapke_k;
    float m = hapke_h(mu0e / k, w) * hapke_h(mue / k, w) - 1.0;
    return k * 0.25 * w * mu0e / (mu0e + mue) * (p * (1.0 + u_hapke_a.w * bs) + m)
           * (1.0 + u_hapke_b.y * bc) * sh;
}

float albedo_scale(vec3 world, vec2 vertex) {
    float a = VERTEX_ALBEDO == 1 ? vertex.x : 1.0;     // exactly 1 otherwise
    if (ALBEDO_MAP == 1) {
        vec2 uv = (world.xy - u_albedo_window.xy) / (u_albedo_window.zw - u_albedo_window.xy);
        a *= texture(u_albedo_map, uv).r;
    }
    return a;
}

// The slope-scaled bias grows with the receiver's depth gradient in light space (its length
// the tangent of the sun's incidence, at most MAX_TAN_INCIDENCE: the sun 2.9 degrees above
// the surface; closer to grazing it would outgrow the map's depth range and light
// everything), each component times the map's texel along that axis. MIN_MU0 keeps the division finite (at
// mu0 = 0.05 the tangent is 19.97, so the two limits agree).
const float MAX_TAN_INCIDENCE = 20.0;
const float MIN_MU0 = 0.05;

// The extended sun (percentage-closer soft shadows, Fernando 2005): the blockers' mean depth
// within the disk a ray can be tilted through (the solar disk's angular radius) gives the
// penumbra's light-space radius, (receiver depth - blocker depth) tan(radius), over which
// the map's comparisons are averaged on a disk of points: the fraction of the solar disk the
// blockers cover, exact for one blocker edge. The blocker search looks at most
// SEARCH_TEXELS of the map's coarser axis away (a receiver farther from every blocker is
// lit by all of the disk unless a penumbra is wider than that).
//
// Cost: a CPU rasteriser runs both sides of every `if` (it masks lanes), but leaves a loop
// as soon as no lane of its fragments goes on, so the filter is a loop whose count is zero
// where the search decides alone: no blocker (lit), every search texel blocked with the
// penumbra inside the searched disk (umbra), or a penumbra under half a texel (the one
// bilinear comparison at the receiver). The search reads BLOCKER_GATHERS x 4 texels with
// textureGather, each texel compared with the receiver's plane at that texel's own centre.
// Both disks of points are Vogel spirals turned by an angle keyed to the pixel (the R2
// sequence, Roberts 2018): fixed per pixel, so frames stay the same bytes, and a few taps
// give noise, not the bands of one fixed pattern, which neighbouring pixels average out.
const int BLOCKER_GATHERS = 4;
const int FILTER_SAMPLES = 16;
const float SEARCH_TEXELS = 24.0;
const float GOLDEN_ANGLE = 2.39996323;
const mat2 GOLDEN_TURN = mat2(cos(GOLDEN_ANGLE), sin(GOLDEN_ANGLE),
                              -sin(GOLDEN_ANGLE), cos(GOLDEN_ANGLE));
const vec2 R2 = vec2(0.75487767, 0.56984029);   // Roberts (2018): 1 / g, 1 / g^2, g^3 = g + 1

float visibility(vec3 n, float mu0, vec3 rel, float shadow_bias) {
    if (SHADOWS == 0 || mu0 <= 0.0) return 1.0;
    vec4 lc = u_light_from_world * vec4(rel + n * u_normal_offset, 1.0);
    vec3 c = lc.xyz / lc.w;
    if (c.x < 0.0 || c.x > 1.0 || c.y < 0.0 || c.y > 1.0 || c.z > 1.0) return 1.0;
    vec3 nl = u_light_axes * n;
    vec2 grad = nl.xy / max(abs(nl.z), MIN_MU0);   // |grad| = tan(incidence)
    grad *= min(1.0, MAX_TAN_INCIDENCE / max(length(grad), 1e-30));
    float ref = c.z - u_bias - shadow_bias
              - u_slope_texels * length(grad * u_texel) / u_depth_range;
    // a point sun: one bilinear comparison (2x2 percentage-closer)
    float centre = texture(u_shadow_map, vec3(c.xy, ref));
    if (SOFT_SHADOWS == 0 || u_sun_tan <= 0.0)
        return centre;
    // the receiver's plane in light space: depth (m) per metre of light-space x and y, so
    // that samples beside the receiver compare with its plane there, not with its own depth
    // (the lit ground up the sun is nearer the sun than the receiver, not in front of it)
    vec2 plane = clamp(nl.xy / max(-nl.z, MIN_MU0), -MAX_TAN_INCIDENCE, MAX_TAN_INCIDENCE)
               / u_depth_range;
    float reach = min(c.z * u_depth_range * u_sun_tan,
                      SEARCH_TEXELS * max(u_texel.x, u_texel.y));
    vec2 to_tex = 1.0 / u_shadow_extent;
    vec2 size = u_shadow_extent / u_texel;          // texels
    vec2 step_depth = plane * u_texel;              // the plane's depth change per texel
    float turn = 6.28318531 * fract(dot(floor(gl_FragCoord.xy), R2));
    vec2 start = vec2(cos(turn), sin(turn));
    vec2 dir = start;
    float blockers = 0.0;
    float distance_sum = 0.0;
    for (int i = 0; i < BLOCKER_GATHERS; ++i) {
        // the first at the receiver, the last at the search's edge
        vec2 at = c.xy * size + sqrt(float(i) / float(BLOCKER_GATHERS - 1)) * reach
                  / u_texel * dir;                  // texels
        dir = GOLDEN_TURN * dir;
        vec4 d = textureGather(u_shadow_depth, at / size);
        // gathered texels: (x0, y1), (x1, y1), (x1, y0), (x0, y0), x0 = floor(at - 0.5)
        vec2 first = floor(at - 0.5) + 0.5 - c.xy * size;  // (x0, y0) from the receiver
        float r00 = ref + dot(step_depth, first);
        vec4 r = vec4(r00 + step_depth.y, r00 + step_depth.x + step_depth.y,
                      r00 + step_depth.x, r00);
        vec4 blocked = vec4(lessThan(d, r));
        blockers += dot(blocked, vec4(1.0));
        distance_sum += dot(blocked, r - d);
    }
    float penumbra = distance_sum / max(blockers, 1.0) * u_depth_range * u_sun_tan;  // m
    bool umbra = blockers == float(4 * BLOCKER_GATHERS) && penumbra <= reach;
    bool sharp = penumbra < 0.5 * min(u_texel.x, u_texel.y);
    int taps = (blockers == 0.0 || umbra || sharp) ? 0 : FILTER_SAMPLES;
    float lit = 0.0;
    dir = start;
    for (int i = 0; i < taps; ++i) {
        vec2 off = sqrt((float(i) + 0.5) / float(FILTER_SAMPLES)) * penumbra * dir;
        dir = GOLDEN_TURN * dir;
        lit += texture(u_shadow_map, vec3(c.xy + off * to_tex, ref + dot(plane, off)));
    }
    if (taps > 0) return lit / float(FILTER_SAMPLES);
    return blockers == 0.0 ? 1.0 : umbra ? 0.0 : centre;
}

// Light from elsewhere than the sun's disk (render.scattering): the terrain's single
// scattering, Lambertian, where the scene holds it; the Earth's, by the surface's own law.
float secondary(vec3 n, vec3 world, vec3 e, float mu, float scale, vec2 vertex) {
    vec2 s = vec2(0.0, 1.0);
    if (SCATTER_MAP == 1)
        s = texture(u_scatter, vec2((world.x - u_scatter_rect.x) * u_scatter_rect.z,
                                    (u_scatter_rect.y - world.y) * u_scatter_rect.w)).rg;
    if (VERTEX_SCATTER == 1)
        s.r = vertex.y;
    float out_f = SCATTERING == 1 ? u_albedo * scale * s.r : 0.0;
    if (EARTHSHINE == 1 && u_earthshine > 0.0) {
        float mu_e = dot(n, u_earth);
        float g_e = degrees(acos(clamp(dot(u_earth, e), -1.0, 1.0)));
        float r_e = BRDF == 3 ? hapke(n, u_earth, e, scale) : reflectance(mu_e, mu, g_e, scale);
        out_f += u_earthshine * s.g * r_e;
    }
    return out_f;
}

void main() {
    ivec2 p = ivec2(gl_FragCoord.xy);
    vec4 surface = texelFetch(u_surface_rel, p, 0);
    vec3 rel = surface.xyz;
    vec3 n = texelFetch(u_surface_normal, p, 0).xyz;
    vec2 vertex = vec2(1.0, 0.0);
    if (VERTEX_ALBEDO == 1 || VERTEX_SCATTER == 1)
        vertex = texelFetch(u_surface_vertex, p, 0).xy;
    vec3 world = rel + u_camera;
    float r = length(rel);
    vec3 e = -rel / r;                         // towards the camera
    float mu0 = dot(n, u_sun);
    float mu = dot(n, e);
    float g = degrees(acos(clamp(dot(u_sun, e), -1.0, 1.0)));
    float scale = albedo_scale(world, vertex);
    float refl = BRDF == 3 ? hapke(n, u_sun, e, scale) : reflectance(mu0, mu, g, scale);
    out_radiance = refl * visibility(n, mu0, rel, surface.w)
                 + secondary(n, world, e, mu, scale, vertex);
    out_range = r;
}
