// Tile compositing of the wgpu forward rasterizer (see render/gpu.rs). One 16×16 workgroup
// per tile, one invocation per pixel; the tile's depth-sorted Gaussians are staged through
// workgroup memory 256 at a time. Same constants and order as the CPU compositor: skip alpha
// below 1/255, clamp at 0.999, stop before transmittance would fall below 1e-4.
// CHANNELS and ACC (= max(CHANNELS, 1)) are substituted by the host before compiling.

const CHANNELS: u32 = {{CHANNELS}}u;
const ACC: u32 = {{ACC}}u;
const ALPHA_MIN: f32 = 0.003921569; // 1/255
const ALPHA_MAX: f32 = 0.999;
const T_MIN: f32 = 1e-4;

struct Params {
    width: u32,
    height: u32,
    tiles_x: u32,
    pixels: u32,
}

@group(0) @binding(0) var<uniform> params: Params;
// Visible Gaussians in depth order ("ranks"), two vec4 each:
// (u, v, conic a, conic b), (conic c, opacity, depth, 0).
@group(0) @binding(1) var<storage, read> gauss: array<vec4<f32>>;
@group(0) @binding(2) var<storage, read> features: array<f32>; // [rank][channel]
@group(0) @binding(3) var<storage, read> tile_offsets: array<u32>;
@group(0) @binding(4) var<storage, read> rank_from_isect: array<u32>;
@group(0) @binding(5) var<storage, read> background: array<f32>;
// [CHANNELS][pixels] features, then [pixels] depth, then [pixels] alpha.
@group(0) @binding(6) var<storage, read_write> output: array<f32>;

var<workgroup> batch_a: array<vec4<f32>, 256>;
var<workgroup> batch_b: array<vec4<f32>, 256>;
var<workgroup> batch_rank: array<u32, 256>;

@compute @workgroup_size(16, 16)
fn main(
    @builtin(workgroup_id) wg: vec3<u32>,
    @builtin(local_invocation_id) lid: vec3<u32>,
    @builtin(local_invocation_index) li: u32,
) {
    let tile = wg.y * params.tiles_x + wg.x;
    let px = wg.x * 16u + lid.x;
    let py = wg.y * 16u + lid.y;
    let inside = px < params.width && py < params.height;
    let centre = vec2<f32>(f32(px) + 0.5, f32(py) + 0.5);
    let start = tile_offsets[tile];
    let end = tile_offsets[tile + 1u];

    var t = 1.0;
    var done = !inside;
    var depth_sum = 0.0;
    var acc: array<f32, ACC>;
    for (var base = start; base < end; base += 256u) {
        workgroupBarrier();
        let idx = base + li;
        if idx < end {
            let rank = rank_from_isect[idx];
            batch_rank[li] = rank;
            batch_a[li] = gauss[2u * rank];
            batch_b[li] = gauss[2u * rank + 1u];
        }
        workgroupBarrier();
        let count = min(256u, end - base);
        for (var j = 0u; j < count && !done; j++) {
            let ga = batch_a[j];
            let gb = batch_b[j];
            let d = centre - ga.xy;
            let power = -0.5 * (ga.z * d.x * d.x + gb.x * d.y * d.y) - ga.w * d.x * d.y;
            let v = gb.y * exp(clamp(power, -87.0, 0.0));
            if v < ALPHA_MIN {
                continue;
            }
            let alpha = min(v, ALPHA_MAX);
            let next = t * (1.0 - alpha);
            if next < T_MIN {
                done = true;
                continue;
            }
            let w = alpha * t;
            let row = batch_rank[j] * CHANNELS;
            for (var c = 0u; c < CHANNELS; c++) {
                acc[c] += w * features[row + c];
            }
            depth_sum += w * gb.z;
            t = next;
        }
    }
    if inside {
        let pix = py * params.width + px;
        for (var c = 0u; c < CHANNELS; c++) {
            output[c * params.pixels + pix] = acc[c] + t * background[c];
        }
        let alpha = 1.0 - t;
        output[CHANNELS * params.pixels + pix] = depth_sum / max(alpha, 1e-10);
        output[(CHANNELS + 1u) * params.pixels + pix] = alpha;
    }
}
