// The Gaussians' drawing order: back to front by view depth, the exact reverse of sfgs::render's front-to-back order
// by (depth, index), so the premultiplied "over" blend adds up what the C++ front-to-back blend does. A stable
// least-significant-digit radix sort of the depths' float32 bits (three passes of 11 bits) keeps equal depths in
// index order; 200k Gaussians sort in a few milliseconds.
"use strict";

const SfgsSort = (() => {
  const DIGIT_BITS = 11;
  const DIGITS = 1 << DIGIT_BITS;

  class DepthSorter {
    constructor(count) {
      this.count = count;
      this.depths = new Float32Array(count);
      this.keys = new Uint32Array(this.depths.buffer);  // the same bytes, read as integers
      this.order = new Uint32Array(count);
      this.scratch = new Uint32Array(count);
      this.backToFront = new Uint32Array(count);
      this.histogram = new Uint32Array(DIGITS);
    }

    // positions: (count x 3) world means; worldToCamera: the row-major 4x4 (its third row gives the depth).
    // Returns the indices farthest first (a view that the next call overwrites).
    sort(positions, worldToCamera) {
      const [r0, r1, r2, t] = [worldToCamera[8], worldToCamera[9], worldToCamera[10], worldToCamera[11]];
      const n = this.count;
      for (let i = 0; i < n; ++i) {
        this.depths[i] = r0 * positions[3 * i] + r1 * positions[3 * i + 1] + r2 * positions[3 * i + 2] + t;
      }
      // IEEE bits order like the numbers once negative values have every bit flipped and positive ones the sign bit.
      for (let i = 0; i < n; ++i) {
        const bits = this.keys[i];
        this.keys[i] = bits & 0x80000000 ? ~bits >>> 0 : (bits | 0x80000000) >>> 0;
      }
      for (let i = 0; i < n; ++i) this.order[i] = i;
      let from = this.order, to = this.scratch;
      for (let shift = 0; shift < 32; shift += DIGIT_BITS) {
        this.histogram.fill(0);
        for (let i = 0; i < n; ++i) ++this.histogram[(this.keys[from[i]] >>> shift) & (DIGITS - 1)];
        let start = 0;
        for (let d = 0; d < DIGITS; ++d) {
          const c = this.histogram[d];
          this.histogram[d] = start;
          start += c;
        }
        for (let i = 0; i < n; ++i) {
          const index = from[i];
          to[this.histogram[(this.keys[index] >>> shift) & (DIGITS - 1)]++] = index;
        }
        [from, to] = [to, from];
      }
      for (let i = 0; i < n; ++i) this.backToFront[i] = from[n - 1 - i];
      return this.backToFront;
    }
  }

  return { DepthSorter };
})();
