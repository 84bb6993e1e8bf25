"""GLSL sources: textured, lit triangles, and the same with a wireframe overlay.

Lighting is Lambert with a directional light plus ambient, from the vertex
normals. It is two-sided (a back face is lit with its normal flipped), because
range scans and terrain borders are open: their back faces are seen.

The wireframe overlay is Baerentzen et al.'s single-pass method (*Single-pass
Wireframe Rendering*, SIGGRAPH 2006 sketch): a geometry shader gives each
corner its screen-space distances to the three edge lines, the fragment
shader darkens pixels within about a pixel of the nearest edge. Hidden edges
stay hidden (no second pass, no depth offset), and edges are anti-aliased.
Triangles crossing the plane of the eye get no overlay (their projected edges
are meaningless there).
"""

VERTEX = """
#version 330
uniform mat4 u_mvp;        // projection * view, relative to u_origin
uniform vec3 u_origin;     // the scene's centre: keeps float32 coordinates small
in vec3 in_position;
in vec3 in_normal;
in vec2 in_uv;
in vec4 in_color;
out vec3 v_normal;
out vec2 v_uv;
out vec4 v_color;
void main() {
    gl_Position = u_mvp * vec4(in_position - u_origin, 1.0);
    v_normal = in_normal;
    v_uv = in_uv;
    v_color = in_color;
}
"""

GEOMETRY = """
#version 330
layout(triangles) in;
layout(triangle_strip, max_vertices = 3) out;
uniform vec2 u_half_viewport;   // pixels from the viewport's centre to its edge
in vec3 v_normal[];
in vec2 v_uv[];
in vec4 v_color[];
out vec3 g_normal;
out vec2 g_uv;
out vec4 g_color;
noperspective out vec3 g_edge;  // pixels to the edge opposite each corner
void main() {
    vec2 p[3];
    bool visible = true;
    for (int i = 0; i < 3; ++i) {
        visible = visible && gl_in[i].gl_Position.w > 0.0;
        p[i] = u_half_viewport * gl_in[i].gl_Position.xy / gl_in[i].gl_Position.w;
    }
    float area = abs((p[1].x - p[0].x) * (p[2].y - p[0].y) - (p[1].y - p[0].y) * (p[2].x - p[0].x));
    vec3 height = vec3(area / max(length(p[2] - p[1]), 1e-6),
                       area / max(length(p[2] - p[0]), 1e-6),
                       area / max(length(p[1] - p[0]), 1e-6));
    for (int i = 0; i < 3; ++i) {
        gl_Position = gl_in[i].gl_Position;
        g_normal = v_normal[i];
        g_uv = v_uv[i];
        g_color = v_color[i];
        vec3 edge = vec3(0.0);
        edge[i] = height[i];
        g_edge = visible ? edge : vec3(1e6);
        EmitVertex();
    }
    EndPrimitive();
}
"""

_FRAGMENT = """
#version 330
uniform sampler2D u_texture;
uniform vec3 u_light;       // unit vector towards the light
uniform float u_ambient;    // light on a face turned away from it, 0..1
uniform bool u_colors;      // multiply by the vertex colours
uniform vec3 u_edge_color;
in vec3 {p}normal;
in vec2 {p}uv;
in vec4 {p}color;
{edge_in}
out vec4 f_color;
void main() {{
    vec3 n = normalize({p}normal);
    if (!gl_FrontFacing) n = -n;
    float light = u_ambient + (1.0 - u_ambient) * max(dot(n, u_light), 0.0);
    vec4 base = texture(u_texture, {p}uv);
    if (u_colors) base *= {p}color;
    vec3 rgb = base.rgb * light;
    {edge_mix}
    f_color = vec4(rgb, 1.0);
}}
"""

FRAGMENT = _FRAGMENT.format(p="v_", edge_in="", edge_mix="")

FRAGMENT_WIREFRAME = _FRAGMENT.format(
    p="g_", edge_in="noperspective in vec3 g_edge;",
    edge_mix="float d = min(g_edge.x, min(g_edge.y, g_edge.z));\n"
             "    rgb = mix(u_edge_color, rgb, smoothstep(0.5, 1.5, d));")
