// The avatar's data (data/*.js: base64 text that `sfgs export --web` wrote, decoded once) and its pose in a frame:
// what sfgs's avatar computes, from the rest pose's Gaussians (docs/web_viewer.md, "What the viewer computes"):
//   [A | t] = sum_k w_k T_jk        the frame's joint transforms blended by the Gaussian's strongest joints
//   mean    = A mu + t + d           d: the frame's offset of the avatar's posed mean (pose correctives, learned and
//                                    structure offsets, hand residual, the joints beyond the strongest), quantised
//   s       = s0 + e                 e: the frame's log-scale offset (the structure offset's scale), quantised
//   Sigma   = exp(2 s) A A^T         as skin::skin_gaussians
//   colour  = albedo * max(0, SH9(n) C)   n: the vertex normal of the rest mesh skinned by the same blends
// All in float64 (JS numbers) from the stored float32 and integer values, as the exporter computed the offsets.
"use strict";

const SfgsPose = (() => {
  const TYPES = { float32: Float32Array, uint32: Uint32Array, int8: Int8Array, uint8: Uint8Array };
  // Texels of one posed Gaussian in the renderer's RGBA32F texture: (mean, opacity), covariance xx xy xz yy,
  // covariance yz zz, (colour, sampling record: 0 without one).
  const TEXELS = 4;

  function decodeBase64(text) {
    const binary = atob(text);
    const bytes = new Uint8Array(binary.length);
    for (let i = 0; i < binary.length; ++i) bytes[i] = binary.charCodeAt(i);
    return bytes.buffer;
  }

  class Avatar {
    // manifest: sfgsExport; data: sfgsData (base64 strings, released here once decoded).
    constructor(manifest, data) {
      this.manifest = manifest;
      this.count = manifest.gaussians;
      this.influences = manifest.influences;
      this.frames = manifest.frames;
      this.files = manifest.files.map((name, k) => {
        if (typeof data[k] !== "string") throw new Error(`the data file ${name} did not load`);
        const buffer = decodeBase64(data[k]);
        data[k] = null;
        return buffer;
      });
      const b = manifest.buffers;
      this.means = this.view(b.means);
      this.logScales = this.view(b.log_scales);
      this.mesh = this.view(b.mesh);
      this.faces = this.view(b.faces);
      this.albedo = this.view(b.albedo);
      this.opacities = this.view(b.opacities);
      this.sampling = b.sampling ? this.view(b.sampling) : null;  // the avatar's sampling record, if it has one
      this.joints = this.view(b.joints);
      this.weights = this.view(b.weights);
      this.shading = manifest.shading;  // (9 x 3) row-major, or null: no shading
      this.weightTotal = manifest.weight_total;  // a Gaussian's 8-bit weights sum to this
      this.colourLevels = manifest.colour_levels;  // albedo and opacity: value x this, rounded
      this.minNormalLength = manifest.min_normal_length;  // body::vertex_normals: a shorter sum gives a zero normal
      this.positions = new Float64Array(3 * this.count);  // the posed means, for the depth sort
      this.posedMesh = new Float64Array(3 * this.count);
      this.normals = new Float64Array(3 * this.count);
    }

    view(entry) {
      return new TYPES[entry.type](this.files[entry.file], entry.offset, entry.length);
    }

    // Frame f's posed Gaussians into `texels` (count x TEXELS x 4 floats) and this.positions.
    pose(f, texels) {
      this.skin(f, texels);
      this.meshNormals();
      this.shade(texels);
    }

    // Means, covariances and opacities, and the skinned rest mesh.
    skin(f, texels) {
      const entry = this.manifest.frame_buffers[f];
      const transforms = this.view(entry.transforms);
      const meanOffsets = this.view(entry.mean_offsets), meanStep = entry.mean_step;
      const scaleOffsets = this.view(entry.log_scale_offsets), scaleStep = entry.log_scale_step;
      const { means, logScales, mesh, opacities, joints, weights, positions, posedMesh } = this;
      const { weightTotal, colourLevels } = this;
      const K = this.influences;
      const a = new Float64Array(12);
      for (let i = 0; i < this.count; ++i) {
        a.fill(0);
        for (let k = 0; k < K; ++k) {
          const w = weights[i * K + k] / weightTotal;
          if (w === 0) continue;  // a Gaussian with fewer influences
          const m = joints[i * K + k] * 12;
          for (let c = 0; c < 12; ++c) a[c] += w * transforms[m + c];
        }
        const x = means[3 * i], y = means[3 * i + 1], z = means[3 * i + 2];
        const px = a[0] * x + a[1] * y + a[2] * z + a[3] + meanOffsets[3 * i] * meanStep;
        const py = a[4] * x + a[5] * y + a[6] * z + a[7] + meanOffsets[3 * i + 1] * meanStep;
        const pz = a[8] * x + a[9] * y + a[10] * z + a[11] + meanOffsets[3 * i + 2] * meanStep;
        positions[3 * i] = px;
        positions[3 * i + 1] = py;
        positions[3 * i + 2] = pz;
        const vx = mesh[3 * i], vy = mesh[3 * i + 1], vz = mesh[3 * i + 2];
        posedMesh[3 * i] = a[0] * vx + a[1] * vy + a[2] * vz + a[3];
        posedMesh[3 * i + 1] = a[4] * vx + a[5] * vy + a[6] * vz + a[7];
        posedMesh[3 * i + 2] = a[8] * vx + a[9] * vy + a[10] * vz + a[11];
        // Sigma = exp(2 s) A A^T with A's rows (a0 a1 a2), (a4 a5 a6), (a8 a9 a10).
        const variance = Math.exp(2 * (logScales[i] + scaleOffsets[i] * scaleStep));
        const o = i * TEXELS * 4;
        texels[o] = px;
        texels[o + 1] = py;
        texels[o + 2] = pz;
        texels[o + 3] = opacities[i] / colourLevels;
        texels[o + 4] = variance * (a[0] * a[0] + a[1] * a[1] + a[2] * a[2]);
        texels[o + 5] = variance * (a[0] * a[4] + a[1] * a[5] + a[2] * a[6]);
        texels[o + 6] = variance * (a[0] * a[8] + a[1] * a[9] + a[2] * a[10]);
        texels[o + 7] = variance * (a[4] * a[4] + a[5] * a[5] + a[6] * a[6]);
        texels[o + 8] = variance * (a[4] * a[8] + a[5] * a[9] + a[6] * a[10]);
        texels[o + 9] = variance * (a[8] * a[8] + a[9] * a[9] + a[10] * a[10]);
      }
    }

    // body::vertex_normals of the skinned rest mesh: the sum of the adjacent faces' cross products (area-weighted),
    // normalised.
    meshNormals() {
      const { faces, posedMesh: v, normals } = this;
      normals.fill(0);
      for (let f = 0; f < faces.length; f += 3) {
        const i0 = 3 * faces[f], i1 = 3 * faces[f + 1], i2 = 3 * faces[f + 2];
        const ex = v[i1] - v[i0], ey = v[i1 + 1] - v[i0 + 1], ez = v[i1 + 2] - v[i0 + 2];
        const gx = v[i2] - v[i0], gy = v[i2 + 1] - v[i0 + 1], gz = v[i2 + 2] - v[i0 + 2];
        const nx = ey * gz - ez * gy, ny = ez * gx - ex * gz, nz = ex * gy - ey * gx;
        normals[i0] += nx;
        normals[i0 + 1] += ny;
        normals[i0 + 2] += nz;
        normals[i1] += nx;
        normals[i1 + 1] += ny;
        normals[i1 + 2] += nz;
        normals[i2] += nx;
        normals[i2 + 1] += ny;
        normals[i2 + 2] += nz;
      }
      for (let i = 0; i < normals.length; i += 3) {
        const length = Math.sqrt(normals[i] ** 2 + normals[i + 1] ** 2 + normals[i + 2] ** 2);
        const scale = length > this.minNormalLength ? 1 / length : 0;
        normals[i] *= scale;
        normals[i + 1] *= scale;
        normals[i + 2] *= scale;
      }
    }

    // Colours: albedo times the shading of the normal (model/shading.h's basis: 1, y, z, x, xy, yz, 3z^2 - 1, xz,
    // x^2 - y^2), clamped at zero.
    shade(texels) {
      const { albedo, normals, colourLevels } = this;
      const c = this.shading;
      for (let i = 0; i < this.count; ++i) {
        const o = i * TEXELS * 4 + 12;
        let r = albedo[3 * i] / colourLevels, g = albedo[3 * i + 1] / colourLevels;
        let b = albedo[3 * i + 2] / colourLevels;
        if (c) {
          const x = normals[3 * i], y = normals[3 * i + 1], z = normals[3 * i + 2];
          const xy = x * y, yz = y * z, zz = 3 * z * z - 1, xz = x * z, xxyy = x * x - y * y;
          r *= Math.max(0, c[0] + y * c[3] + z * c[6] + x * c[9] + xy * c[12] + yz * c[15] + zz * c[18] +
                           xz * c[21] + xxyy * c[24]);
          g *= Math.max(0, c[1] + y * c[4] + z * c[7] + x * c[10] + xy * c[13] + yz * c[16] + zz * c[19] +
                           xz * c[22] + xxyy * c[25]);
          b *= Math.max(0, c[2] + y * c[5] + z * c[8] + x * c[11] + xy * c[14] + yz * c[17] + zz * c[20] +
                           xz * c[23] + xxyy * c[26]);
        }
        texels[o] = r;
        texels[o + 1] = g;
        texels[o + 2] = b;
        texels[o + 3] = this.sampling ? this.sampling[i] : 0;
      }
    }
  }

  return { Avatar, TEXELS };
})();
