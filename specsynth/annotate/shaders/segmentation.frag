#version 330 core
// pyrender's segmentation shader; a primitive with texture coordinates is one whose material has
// a coverage map: where the map is below one half, the surface is a hole (leaves, fences, cards).
uniform vec3 color;
#ifdef TEXCOORD_0_LOC
in vec2 uv;
uniform sampler2D coverage;
uniform vec3 uv_row0;  // the material's UV transform: u' = dot(uv_row0, (u, v, 1))
uniform vec3 uv_row1;
#endif
out vec4 frag_color;

void main()
{
#ifdef TEXCOORD_0_LOC
    vec3 h = vec3(uv, 1.0);
    if (texture(coverage, vec2(dot(uv_row0, h), dot(uv_row1, h))).r < 0.5) discard;
#endif
    frag_color = vec4(color, 1.0);
}
