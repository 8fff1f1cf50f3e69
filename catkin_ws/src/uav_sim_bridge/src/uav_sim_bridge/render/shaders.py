"""GLSL 3.30 shaders of the renderer: one multi-render-target pass and a sky pass.

Outputs (``location``): 0 RGBA8 color, 1 R32F z-depth in metres, 2 R32UI instance id.
The instance-only pass (``INSTANCE_*``) writes just the R32UI ids at location 0:
ground-truth detections need nothing else, and shading is what costs.
The color is the vertex base color times a world-space value-noise texture (three
octaves, faded out where a texel gets smaller than a pixel), lit by a sun, a sky and an
ambient term (colours from :class:`~uav_sim_bridge.core.lighting.Lighting`), faded into
haze or fog with distance.  Around home the terrain gets a concrete landing pad with an "H".

Shadows: the world seen from the sun is a depth map (:data:`DEPTH_VS`): the static world is rendered
into it once per sun position, and the people and vehicles are drawn into it where they stand
whenever they move. On llvmpipe every texture lookup in the main pass costs 15-25 % of a frame, so
the main pass does none: with ``#define SHADOWS`` it writes, in the colour's alpha, the share of
each pixel's light that comes from the sun. A reduced-resolution pass (:data:`SHADOW_FS`, one pixel
per ``shadow_step`` x ``shadow_step`` block) then puts each block back into the world from its z-depth
and looks it up in the shadow map (hardware 2x2 percentage-closer filtering); the renderer
interpolates that back to full resolution and takes the sun's share away where it is shadowed.

Speed (Mesa llvmpipe runs every fragment shader on the CPU, and a branch costs both of its
sides): the haze is computed per vertex (it changes by < 1e-4 across a triangle), and the
landing pad's per-pixel test is compiled in only with ``#define PAD`` (:func:`with_defines`),
the variant the renderer uses for the few tiles that touch the pad.
"""

from __future__ import annotations

MAIN_VS = """
#version 330
uniform mat4 u_mvp;
uniform mat4 u_view;
uniform vec3 u_eye;
uniform float u_haze_per_m;
uniform float u_haze_max;
in vec3 in_pos;
in vec3 in_nrm;
in vec3 in_col;
in uint in_inst;
out vec3 v_pos;
out vec3 v_nrm;
out vec3 v_col;
out float v_z;
out float v_haze;
flat out uint v_inst;
void main() {
    v_pos = in_pos;
    v_nrm = in_nrm;
    v_col = in_col;
    v_inst = in_inst;
    v_z = -(u_view * vec4(in_pos, 1.0)).z;
    v_haze = u_haze_max * (1.0 - exp(-length(in_pos - u_eye) * u_haze_per_m));
    gl_Position = u_mvp * vec4(in_pos, 1.0);
}
"""

MAIN_FS = """
#version 330
uniform vec3 u_sun;
uniform vec3 u_sun_rgb;
uniform vec3 u_sky_rgb;
uniform vec3 u_ambient_rgb;
uniform float u_focal_px;
uniform float u_texture_gain;
uniform float u_pad_half_m;
uniform uint u_pad_instance;
uniform vec3 u_haze_color;
in vec3 v_pos;
in vec3 v_nrm;
in vec3 v_col;
in float v_z;
in float v_haze;
flat in uint v_inst;
layout(location = 0) out vec4 f_color;
layout(location = 1) out float f_depth;
layout(location = 2) out uint f_inst;

float hash3(vec3 p) {
    p = fract(p * 0.3183099 + 0.1);
    p *= 17.0;
    return fract(p.x * p.y * p.z * (p.x + p.y + p.z));
}
float vnoise(vec3 x) {
    vec3 i = floor(x);
    vec3 f = fract(x);
    f = f * f * (3.0 - 2.0 * f);
    return mix(mix(mix(hash3(i), hash3(i + vec3(1, 0, 0)), f.x),
                   mix(hash3(i + vec3(0, 1, 0)), hash3(i + vec3(1, 1, 0)), f.x), f.y),
               mix(mix(hash3(i + vec3(0, 0, 1)), hash3(i + vec3(1, 0, 1)), f.x),
                   mix(hash3(i + vec3(0, 1, 1)), hash3(i + vec3(1, 1, 1)), f.x), f.y), f.z);
}
// one octave with cell size `cell_m`, faded to its mean once a cell covers < ~1.5 pixels
float octave(vec3 p, float cell_m, float px_m) {
    float w = clamp((cell_m / px_m - 1.5) / 2.0, 0.0, 1.0);
    return mix(0.5, vnoise(p / cell_m), w);
}
#ifdef PAD
vec3 pad(vec3 base) {
    vec2 q = abs(v_pos.xy);
    if (max(q.x, q.y) > u_pad_half_m) return base;
    vec3 c = vec3(0.62, 0.62, 0.60);
    float r = length(v_pos.xy);
    if (abs(r - 0.72 * u_pad_half_m) < 0.35) c = vec3(0.95, 0.80, 0.15);
    vec2 h = v_pos.xy / (0.45 * u_pad_half_m);
    bool bar = abs(h.x) > 0.55 && abs(h.x) < 0.85 && abs(h.y) < 1.0;
    bool mid = abs(h.x) <= 0.55 && abs(h.y) < 0.15;
    if (bar || mid) c = vec3(0.95, 0.95, 0.93);
    return c;
}
#endif
void main() {
    vec3 n = normalize(v_nrm);
    if (!gl_FrontFacing) n = -n;
    float px_m = max(v_z, 1e-3) / u_focal_px;
    float tex = 0.5 * octave(v_pos, 0.45, px_m) + 0.3 * octave(v_pos, 1.7, px_m) + 0.2 * octave(v_pos, 7.0, px_m);
    tex = 1.0 + u_texture_gain * (tex - 0.5);
    vec3 base = v_col;
#ifdef PAD
    if (v_inst == u_pad_instance) base = pad(base);
#endif
    float sun = max(dot(n, u_sun), 0.0);
    float sky = 0.5 + 0.5 * n.z;
    vec3 sun_rgb = u_sun_rgb * sun;
    vec3 light = sun_rgb + u_sky_rgb * sky + u_ambient_rgb;
    vec3 lit_rgb = base * tex * light;
#ifdef SHADOWS
    // the share of this pixel's colour that the sun gives (haze included): what a shadow takes away
    const vec3 lum = vec3(0.299, 0.587, 0.114);
    float sun_share = dot(sun_rgb, lum) / max(dot(light, lum), 1e-4) * (1.0 - v_haze);
    f_color = vec4(clamp(mix(lit_rgb, u_haze_color, v_haze), 0.0, 1.0), sun_share);
#else
    f_color = vec4(clamp(mix(lit_rgb, u_haze_color, v_haze), 0.0, 1.0), 1.0);
#endif
    f_depth = v_z;
    f_inst = v_inst;
}
"""


def with_defines(source: str, *names: str) -> str:
    """``source`` with ``#define NAME`` lines after its ``#version`` line (which must come first)."""
    version, sep, rest = source.lstrip("\n").partition("\n")
    if not version.startswith("#version"):
        msg = "a GLSL source must start with its #version line"
        raise ValueError(msg)
    return version + sep + "".join(f"#define {n}\n" for n in names) + rest


SKY_VS = """
#version 330
in vec2 in_xy;
void main() { gl_Position = vec4(in_xy, 1.0, 1.0); }
"""

SKY_FS = """
#version 330
uniform mat3 u_r_map_optical;
uniform vec4 u_k;       // fx fy cx cy
uniform float u_height;
uniform vec3 u_sun;
uniform vec3 u_zenith;
uniform vec3 u_horizon;
uniform vec3 u_glow;
uniform float u_sun_disc;
layout(location = 0) out vec4 f_color;
layout(location = 1) out float f_depth;
layout(location = 2) out uint f_inst;
void main() {
    // window coordinates -> OpenCV pixel (row 0 at the top, pixel centres at integers)
    vec2 px = vec2(gl_FragCoord.x - 0.5, u_height - gl_FragCoord.y - 0.5);
    vec3 ray = vec3((px.x - u_k.z) / u_k.x, (px.y - u_k.w) / u_k.y, 1.0);
    vec3 d = normalize(u_r_map_optical * ray);
    float t = clamp(d.z, 0.0, 1.0);
    vec3 c = mix(u_horizon, u_zenith, pow(t, 0.6));
    float toward = max(dot(d, u_sun), 0.0);
    c += u_glow * pow(toward, 6.0) * (1.0 - 0.7 * t);
    c += u_sun_disc * vec3(1.0, 0.95, 0.8) * pow(toward, 200.0);
    f_color = vec4(clamp(c, 0.0, 1.0), 1.0);
    f_depth = uintBitsToFloat(0x7FC00000u);  // quiet NaN: no return
    f_inst = 0u;
}
"""

INSTANCE_VS = """
#version 330
uniform mat4 u_mvp;
in vec3 in_pos;
in uint in_inst;
flat out uint v_inst;
void main() {
    v_inst = in_inst;
    gl_Position = u_mvp * vec4(in_pos, 1.0);
}
"""

INSTANCE_FS = """
#version 330
flat in uint v_inst;
layout(location = 0) out uint f_inst;
void main() { f_inst = v_inst; }
"""

DEPTH_VS = """
#version 330
uniform mat4 u_light;
in vec3 in_pos;
void main() { gl_Position = u_light * vec4(in_pos, 1.0); }
"""

DEPTH_FS = """
#version 330
void main() {}
"""


SHADOW_VS = """
#version 330
in vec2 in_xy;
void main() { gl_Position = vec4(in_xy, 0.0, 1.0); }
"""

# One pixel per block of the camera image: back into the world from its z-depth, into the shadow map.
SHADOW_FS = """
#version 330
uniform sampler2D u_depth;          // the camera pass's z-depth (metres; 0 or NaN: nothing there)
uniform sampler2DShadow u_shadow;   // the world seen from the sun
uniform mat3 u_r_map_optical;
uniform vec3 u_eye;
uniform vec4 u_k;                   // fx fy cx cy of the full-resolution camera
uniform float u_height;             // full-resolution image height
uniform mat4 u_light;               // map -> shadow map [0, 1]^3
uniform float u_bias;               // shadow-map depth bias
uniform int u_step;                 // camera pixels per shadow pixel, along each axis
layout(location = 0) out float f_lit;
void main() {
    // the block's centre pixel in the full-resolution target (bottom-up)
    ivec2 px = ivec2(gl_FragCoord.xy) * u_step + ivec2(u_step / 2);
    float z = texelFetch(u_depth, px, 0).r;
    if (!(z > 0.0)) { f_lit = 1.0; return; }
    vec2 cv = vec2(float(px.x), u_height - 1.0 - float(px.y));  // OpenCV pixel (row 0 at the top)
    vec3 p = u_r_map_optical * vec3((cv.x - u_k.z) / u_k.x * z, (cv.y - u_k.w) / u_k.y * z, z) + u_eye;
    vec3 ls = (u_light * vec4(p, 1.0)).xyz;
    f_lit = texture(u_shadow, vec3(ls.xy, clamp(ls.z - u_bias, 0.0, 1.0)));
}
"""
