// Colour by data (docs/ARCHITECTURE.md, Colour by data): after a batch's traversal rounds, every hit
// on a mesh coloured by data reads its triangle's attributes from the attribute blocks and
// writes its albedo: a scalar (interpolated at the hit for point data, as ParaView interpolates
// scalars before mapping) through the mesh's colormap, or a direct colour. A rank that lacks the
// attribute block faults it like any block (`locate`) and leaves the slot unresolved; the host
// serves the round's faults and dispatches again, and resolved slots are skipped. Rays that only
// traverse never read an attribute block. Slots: wave_slot(i, albedo_stride - 1, albedo_stride),
// the last ray of the pixel's wave (ambient occlusion reads no albedo).
#import params
#import ray
#import blocks
#import dc
#import scene
#import tiles
#import colormap

// Fixed for a model: triangles per attribute block, words per triangle (1: per triangle, 3: per
// corner).
override ATTRS_PER_BLOCK: u32 = 2048u;
override ATTR_WORDS: u32 = 1u;

@group(1) @binding(0) var<storage, read> rays: array<RayGroups>;
// xyz the albedo, w 1 once resolved (the host clears the buffer before the first dispatch).
@group(1) @binding(4) var<storage, read_write> albedos: array<vec4<f32>>;

@compute @workgroup_size(64)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    let i = gid.x;
    if i >= params.batch_rays {
        return;
    }
    let j = wave_slot(i, params.albedo_stride - 1u, params.albedo_stride);
    if albedos[j].w != 0.0 {
        return;
    }
    let r = ray_state(rays[j]);
    if r.hit == NONE || r.status != DONE {
        return;
    }
    let m = meshes[mesh_of(r.prim)];
    if m.look == LOOK_CONSTANT {
        return;
    }
    let b = r.hit / ATTRS_PER_BLOCK;
    let row = locate(params.attr_block0 + b);
    if row == NONE {
        return;
    }
    let w = (r.hit - b * ATTRS_PER_BLOCK) * ATTR_WORDS;
    var c: vec3<f32>;
    if m.look == LOOK_SCALARS {
        var s = bitcast<f32>(word_at(row, w));
        if m.point != 0u {
            let s1 = bitcast<f32>(word_at(row, w + 1u));
            let s2 = bitcast<f32>(word_at(row, w + 2u));
            s = s + r.b1 * (s1 - s) + r.b2 * (s2 - s);
        }
        c = colormap(s, m.lo, m.scale, m.map);
    } else {
        c = srgb_color(word_at(row, w));
        if m.point != 0u {
            let c1 = srgb_color(word_at(row, w + 1u));
            let c2 = srgb_color(word_at(row, w + 2u));
            c = c + r.b1 * (c1 - c) + r.b2 * (c2 - c);
        }
    }
    albedos[j] = vec4(c, 1.0);
}
