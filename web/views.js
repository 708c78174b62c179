// The input photos under the 3D view, each with the masks of the highlighted instances
// painted over it (from the query answer's run-length encoded masks).

import { HIGHLIGHT } from "./colours.js";

/** A canvas of the mask `rle` ({width, height, counts}, row-major, starting with zeros). */
function maskCanvas({ width, height, counts }) {
  const canvas = new OffscreenCanvas(width, height);
  const ctx = canvas.getContext("2d");
  const image = ctx.createImageData(width, height);
  let at = 0;
  counts.forEach((run, i) => {
    if (i % 2 === 1) {
      for (let p = at; p < at + run; p++) image.data.set([...HIGHLIGHT, 150], 4 * p);
    }
    at += run;
  });
  ctx.putImageData(image, 0, 0);
  return canvas;
}

export class Views {
  constructor(container) {
    this.container = container;
    this.views = [];
  }

  /** Shows `photos` (Blobs), one canvas each, in view order. */
  async show(photos) {
    this.container.replaceChildren();
    this.views = await Promise.all(photos.map((p) => createImageBitmap(p)));
    this.canvases = this.views.map((bitmap, i) => {
      const canvas = document.createElement("canvas");
      [canvas.width, canvas.height] = [bitmap.width, bitmap.height];
      canvas.title = `view ${i}`;
      this.container.append(canvas);
      return canvas;
    });
    this.paint([]);
  }

  /** Redraws every photo with the masks of `matches` (a query answer's) over it. */
  paint(matches) {
    this.canvases.forEach((canvas, view) => {
      const ctx = canvas.getContext("2d");
      ctx.drawImage(this.views[view], 0, 0);
      for (const mask of matches.flatMap((m) => m.masks).filter((m) => m.view === view)) {
        ctx.drawImage(maskCanvas(mask.rle), 0, 0, canvas.width, canvas.height);
      }
    });
  }
}
