// Reads what the page needs from inssplat's scene.ply (binary little-endian 3DGS PLY with
// extra properties): each Gaussian's RGB colour and opacity, its instance id, and the extent of
// the centres. The renderer reads the same file for the splats themselves; both keep the file's
// order, so index i here is splat i there.

const SH_C0 = 0.28209479177387814;

const TYPES = {
  char: ["getInt8", 1], uchar: ["getUint8", 1], short: ["getInt16", 2], ushort: ["getUint16", 2],
  int: ["getInt32", 4], uint: ["getUint32", 4], float: ["getFloat32", 4], double: ["getFloat64", 8],
  int8: ["getInt8", 1], uint8: ["getUint8", 1], int16: ["getInt16", 2], uint16: ["getUint16", 2],
  int32: ["getInt32", 4], uint32: ["getUint32", 4], float32: ["getFloat32", 4], float64: ["getFloat64", 8],
};

/** The header: vertex count, byte offset of the data, and each property's reader and offset. */
function header(bytes) {
  const end = new TextDecoder().decode(bytes.subarray(0, Math.min(bytes.length, 65536))).indexOf("end_header\n");
  if (end < 0) throw new Error("scene.ply has no end_header");
  const lines = new TextDecoder().decode(bytes.subarray(0, end)).split("\n");
  if (!lines.includes("format binary_little_endian 1.0")) throw new Error("scene.ply is not binary little-endian");
  let count = 0;
  let stride = 0;
  let inVertex = false;
  const props = {};
  for (const line of lines) {
    const words = line.trim().split(/\s+/);
    if (words[0] === "element") {
      inVertex = words[1] === "vertex";
      if (inVertex) count = Number(words[2]);
    } else if (words[0] === "property" && inVertex) {
      const type = TYPES[words[1]];
      if (!type) throw new Error(`scene.ply: unsupported property type ${words[1]}`);
      props[words[2]] = { get: type[0], offset: stride };
      stride += type[1];
    }
  }
  for (const name of ["x", "y", "z", "f_dc_0", "f_dc_1", "f_dc_2", "opacity", "instance_id"]) {
    if (!props[name]) throw new Error(`scene.ply has no ${name} property`);
  }
  return { count, stride, data: end + "end_header\n".length, props };
}

/** The Gaussians of `buffer` (an ArrayBuffer of scene.ply). */
export function readScene(buffer) {
  const bytes = new Uint8Array(buffer);
  const { count, stride, data, props } = header(bytes);
  const view = new DataView(buffer);
  const read = (i, name) => view[props[name].get](data + i * stride + props[name].offset, true);
  const rgba = new Uint8Array(count * 4);
  const instanceIds = new Uint32Array(count);
  const centre = [0, 0, 0];
  const byte = (v) => Math.max(0, Math.min(255, Math.round(v * 255)));
  for (let i = 0; i < count; i++) {
    for (let c = 0; c < 3; c++) rgba[4 * i + c] = byte(0.5 + SH_C0 * read(i, `f_dc_${c}`));
    rgba[4 * i + 3] = byte(1 / (1 + Math.exp(-read(i, "opacity"))));
    instanceIds[i] = read(i, "instance_id");
    centre[0] += read(i, "x") / count;
    centre[1] += read(i, "y") / count;
    centre[2] += read(i, "z") / count;
  }
  let radius = 0;
  for (let i = 0; i < count; i++) {
    const d = Math.hypot(read(i, "x") - centre[0], read(i, "y") - centre[1], read(i, "z") - centre[2]);
    radius += d / count;
  }
  return { count, rgba, instanceIds, centre, radius };
}
