// The colours the page paints with: one per instance id (the same in the 3D view, the
// instance list and the masks), and the highlight of a query.

/** Highlighted Gaussians and mask pixels. */
export const HIGHLIGHT = [255, 0, 255];
/** What the rest of the scene fades to while something is highlighted. */
export const DIMMED = [70, 70, 70];
/** The 3D view's background. */
export const BACKGROUND = 0x15171c;

/** A stable, well-spread colour for instance `id` (0 = no instance: grey); the hues stop
 * short of purple and magenta, which belong to the highlight. */
export function instanceColour(id) {
  if (id === 0) return [128, 128, 128];
  const hue = ((id * 0.618033988749895) % 1) * 0.72;
  const f = (n) => {
    const k = (n + hue * 12) % 12;
    return Math.round(255 * (0.55 - 0.4 * Math.max(-1, Math.min(k - 3, 9 - k, 1))));
  };
  return [f(0), f(8), f(4)];
}

export function css([r, g, b]) {
  return `rgb(${r} ${g} ${b})`;
}
