// WebGL2 splatting with sfgs::render's arithmetic (csrc/ops/splat/pair_math.h): each Gaussian's EWA projection with the
// field-of-view guard and the low-pass dilation, an instanced quad over its alpha >= min_alpha ellipse, alpha =
// min(max_alpha, opacity exp(-sigma)) at the pixel centres, premultiplied back to front into a float render target
// (so no 8-bit rounding accumulates), then presented rounded to 8 bits as the C++ PNGs are. The blend has no early
// termination (sfgs stops a pixel once its transmittance would fall below 1e-4): docs/web_viewer.md measures it.
"use strict";

const SfgsRenderer = (() => {
  const TEXTURE_WIDTH = 4096;  // texels a row: 1024 Gaussians of 4 texels

  const SPLAT_VERTEX = `#version 300 es
precision highp float;
precision highp int;
precision highp sampler2D;
uniform sampler2D u_gaussians;
uniform mat3 u_rotation;      // world to camera
uniform vec3 u_translation;
uniform vec4 u_intrinsics;    // fx, fy, cx, cy (pixels)
uniform vec2 u_size;          // width, height (pixels)
uniform vec2 u_clip;          // near, far
uniform float u_low_pass, u_min_alpha, u_fov_guard, u_psd_tolerance, u_min_determinant;
in vec2 a_corner;             // (+-1, +-1)
in uint a_index;              // the Gaussian, per instance, in drawing order
flat out vec2 v_mean;         // pixels
flat out vec3 v_conic;
flat out vec4 v_colour;       // rgb, opacity

vec4 texel(int k) { return texelFetch(u_gaussians, ivec2(k % ${TEXTURE_WIDTH}, k / ${TEXTURE_WIDTH}), 0); }

void cull() { gl_Position = vec4(0.0, 0.0, 2.0, 1.0); }  // beyond the far clip plane: no fragments

void main() {
  int base = int(a_index) * 4;
  vec4 t0 = texel(base), t1 = texel(base + 1), t2 = texel(base + 2), t3 = texel(base + 3);
  mat3 covariance = mat3(t1.x, t1.y, t1.z, t1.y, t1.w, t2.x, t1.z, t2.x, t2.y);
  vec3 p = u_rotation * t0.xyz + u_translation;
  float z = p.z, opacity = t0.w;
  if (!(z >= u_clip.x && z <= u_clip.y) || !(opacity >= u_min_alpha)) { cull(); return; }
  float fx = u_intrinsics.x, fy = u_intrinsics.y, cx = u_intrinsics.z, cy = u_intrinsics.w;
  // The sampling filter (csrc/model/sampling_filter.h; t3.w the record): where this view samples the Gaussian more
  // finely than training did, an isotropic variance that makes the low-pass the training's.
  float footprint = z / sqrt(fx * fy);
  mat3 camera_cov = u_rotation * covariance * transpose(u_rotation) +
                    mat3(u_low_pass * max(0.0, t3.w * t3.w - footprint * footprint));
  float guard_x = u_fov_guard * 0.5 * u_size.x / fx, guard_y = u_fov_guard * 0.5 * u_size.y / fy;
  float tx = clamp(p.x / z, -cx / fx - guard_x, (u_size.x - cx) / fx + guard_x);
  float ty = clamp(p.y / z, -cy / fy - guard_y, (u_size.y - cy) / fy + guard_y);
  vec3 j0 = vec3(fx / z, 0.0, -fx * tx / z), j1 = vec3(0.0, fy / z, -fy * ty / z);
  vec3 s0 = camera_cov * j0, s1 = camera_cov * j1;
  float a0 = dot(j0, s0), b = 0.5 * (dot(j0, s1) + dot(j1, s0)), c0 = dot(j1, s1);
  if (!(a0 >= 0.0 && c0 >= 0.0 && a0 * c0 - b * b >= -u_psd_tolerance * a0 * c0)) { cull(); return; }
  float a = a0 + u_low_pass, c = c0 + u_low_pass, det = a * c - b * b;
  if (!(det > u_min_determinant)) { cull(); return; }
  float level = log(opacity / u_min_alpha);
  v_conic = vec3(c / det, -b / det, a / det);
  v_mean = vec2(fx * (p.x / z) + cx, fy * (p.y / z) + cy);
  v_colour = vec4(t3.rgb, opacity);
  // The ellipse's bounding box plus a pixel: which pixel centres blend is the fragment's alpha test, as in sfgs.
  vec2 extent = sqrt(2.0 * level * vec2(a, c)) + 1.0;
  vec2 pixel = v_mean + a_corner * extent;
  gl_Position = vec4(2.0 * pixel.x / u_size.x - 1.0, 1.0 - 2.0 * pixel.y / u_size.y, 0.0, 1.0);
}`;

  const SPLAT_FRAGMENT = `#version 300 es
precision highp float;
uniform float u_height, u_min_alpha, u_max_alpha;
flat in vec2 v_mean;
flat in vec3 v_conic;
flat in vec4 v_colour;
out vec4 colour;
void main() {
  vec2 d = vec2(gl_FragCoord.x, u_height - gl_FragCoord.y) - v_mean;  // pixel centres at +0.5, y down
  float sigma = 0.5 * (v_conic.x * d.x * d.x + v_conic.z * d.y * d.y) + v_conic.y * d.x * d.y;
  if (sigma < 0.0) discard;
  float alpha = min(u_max_alpha, v_colour.a * exp(-sigma));
  if (alpha < u_min_alpha) discard;
  colour = vec4(v_colour.rgb * alpha, alpha);
}`;

  const PRESENT_VERTEX = `#version 300 es
void main() { gl_Position = vec4(gl_VertexID == 1 ? 3.0 : -1.0, gl_VertexID == 2 ? 3.0 : -1.0, 0.0, 1.0); }`;

  const PRESENT_FRAGMENT = `#version 300 es
precision highp float;
uniform sampler2D u_image;
out vec4 colour;
// Rounded to 8 bits here as the C++ PNGs are (clamp, x 255, round), so the canvas stores exactly those bytes.
void main() {
  vec3 c = texelFetch(u_image, ivec2(gl_FragCoord.xy), 0).rgb;
  colour = vec4(floor(clamp(c, 0.0, 1.0) * 255.0 + 0.5) / 255.0, 1.0);
}`;

  function compile(gl, vertexSource, fragmentSource) {
    const program = gl.createProgram();
    for (const [type, source] of [[gl.VERTEX_SHADER, vertexSource], [gl.FRAGMENT_SHADER, fragmentSource]]) {
      const shader = gl.createShader(type);
      gl.shaderSource(shader, source);
      gl.compileShader(shader);
      if (!gl.getShaderParameter(shader, gl.COMPILE_STATUS)) throw new Error(gl.getShaderInfoLog(shader));
      gl.attachShader(program, shader);
    }
    gl.linkProgram(program);
    if (!gl.getProgramParameter(program, gl.LINK_STATUS)) throw new Error(gl.getProgramInfoLog(program));
    return program;
  }

  class Renderer {
    // splatting: the manifest's thresholds of sfgs::render; background: rgb.
    constructor(canvas, count, splatting, background) {
      const gl = canvas.getContext("webgl2", { antialias: false, alpha: false, depth: false,
                                               preserveDrawingBuffer: true });
      if (!gl) throw new Error("this browser has no WebGL2");
      if (!gl.getExtension("EXT_color_buffer_float")) {
        throw new Error("this browser cannot render into float targets (EXT_color_buffer_float)");
      }
      // Float32 blending where the browser has it; half floats (11 bits) otherwise.
      this.targetFormat = gl.getExtension("EXT_float_blend") ? gl.RGBA32F : gl.RGBA16F;
      this.gl = gl;
      this.canvas = canvas;
      this.count = count;
      this.background = background;
      this.splat = compile(gl, SPLAT_VERTEX, SPLAT_FRAGMENT);
      this.present = compile(gl, PRESENT_VERTEX, PRESENT_FRAGMENT);
      this.uniforms = {};
      for (const name of ["u_gaussians", "u_rotation", "u_translation", "u_intrinsics", "u_size", "u_clip",
                          "u_low_pass", "u_min_alpha", "u_fov_guard", "u_psd_tolerance", "u_min_determinant",
                          "u_height", "u_max_alpha"]) {
        this.uniforms[name] = gl.getUniformLocation(this.splat, name);
      }
      gl.useProgram(this.splat);
      gl.uniform1f(this.uniforms.u_low_pass, splatting.low_pass_variance);
      gl.uniform1f(this.uniforms.u_min_alpha, splatting.min_alpha);
      gl.uniform1f(this.uniforms.u_max_alpha, splatting.max_alpha);
      gl.uniform1f(this.uniforms.u_fov_guard, splatting.fov_guard_fraction);
      gl.uniform1f(this.uniforms.u_psd_tolerance, splatting.psd_tolerance);
      gl.uniform1f(this.uniforms.u_min_determinant, splatting.min_determinant);

      this.rows = Math.ceil((count * 4) / TEXTURE_WIDTH);
      this.texels = new Float32Array(TEXTURE_WIDTH * this.rows * 4);
      this.gaussians = gl.createTexture();
      gl.bindTexture(gl.TEXTURE_2D, this.gaussians);
      gl.texStorage2D(gl.TEXTURE_2D, 1, gl.RGBA32F, TEXTURE_WIDTH, this.rows);
      for (const p of [gl.TEXTURE_MIN_FILTER, gl.TEXTURE_MAG_FILTER]) gl.texParameteri(gl.TEXTURE_2D, p, gl.NEAREST);

      this.vertexArray = gl.createVertexArray();
      gl.bindVertexArray(this.vertexArray);
      const corners = gl.createBuffer();
      gl.bindBuffer(gl.ARRAY_BUFFER, corners);
      gl.bufferData(gl.ARRAY_BUFFER, new Float32Array([-1, -1, 1, -1, -1, 1, 1, 1]), gl.STATIC_DRAW);
      const cornerLocation = gl.getAttribLocation(this.splat, "a_corner");
      gl.enableVertexAttribArray(cornerLocation);
      gl.vertexAttribPointer(cornerLocation, 2, gl.FLOAT, false, 0, 0);
      this.order = gl.createBuffer();
      gl.bindBuffer(gl.ARRAY_BUFFER, this.order);
      gl.bufferData(gl.ARRAY_BUFFER, count * 4, gl.DYNAMIC_DRAW);
      const indexLocation = gl.getAttribLocation(this.splat, "a_index");
      gl.enableVertexAttribArray(indexLocation);
      gl.vertexAttribIPointer(indexLocation, 1, gl.UNSIGNED_INT, 0, 0);
      gl.vertexAttribDivisor(indexLocation, 1);
      gl.bindVertexArray(null);
      this.target = null;
    }

    // The posed Gaussians' texels (SfgsPose.Avatar.pose wrote them into this.texels).
    uploadGaussians() {
      const gl = this.gl;
      gl.bindTexture(gl.TEXTURE_2D, this.gaussians);
      gl.texSubImage2D(gl.TEXTURE_2D, 0, 0, 0, TEXTURE_WIDTH, this.rows, gl.RGBA, gl.FLOAT, this.texels);
    }

    // The drawing order: Gaussian indices, farthest first.
    uploadOrder(order) {
      const gl = this.gl;
      gl.bindBuffer(gl.ARRAY_BUFFER, this.order);
      gl.bufferSubData(gl.ARRAY_BUFFER, 0, order);
    }

    // The float render target, (re)made at the canvas's size.
    ensureTarget() {
      const gl = this.gl, width = this.canvas.width, height = this.canvas.height;
      if (this.target && this.target.width === width && this.target.height === height) return;
      if (this.target) {
        gl.deleteFramebuffer(this.target.framebuffer);
        gl.deleteTexture(this.target.texture);
      }
      const texture = gl.createTexture();
      gl.bindTexture(gl.TEXTURE_2D, texture);
      gl.texStorage2D(gl.TEXTURE_2D, 1, this.targetFormat, width, height);
      // Float textures are complete only without filtering (unless OES_texture_float_linear): read texel by texel.
      for (const p of [gl.TEXTURE_MIN_FILTER, gl.TEXTURE_MAG_FILTER]) gl.texParameteri(gl.TEXTURE_2D, p, gl.NEAREST);
      const framebuffer = gl.createFramebuffer();
      gl.bindFramebuffer(gl.FRAMEBUFFER, framebuffer);
      gl.framebufferTexture2D(gl.FRAMEBUFFER, gl.COLOR_ATTACHMENT0, gl.TEXTURE_2D, texture, 0);
      if (gl.checkFramebufferStatus(gl.FRAMEBUFFER) !== gl.FRAMEBUFFER_COMPLETE) {
        throw new Error("this browser cannot render into a float target of the canvas's size");
      }
      this.target = { texture, framebuffer, width, height };
    }

    // camera: {worldToCamera (row-major 4x4), fx, fy, cx, cy, near, far} for the canvas's size.
    draw(camera) {
      const gl = this.gl, u = this.uniforms, w = camera.worldToCamera;
      this.ensureTarget();
      const { width, height } = this.target;
      gl.bindFramebuffer(gl.FRAMEBUFFER, this.target.framebuffer);
      gl.viewport(0, 0, width, height);
      gl.clearColor(this.background[0], this.background[1], this.background[2], 0);
      gl.clear(gl.COLOR_BUFFER_BIT);
      gl.enable(gl.BLEND);
      gl.blendFunc(gl.ONE, gl.ONE_MINUS_SRC_ALPHA);
      gl.useProgram(this.splat);
      gl.activeTexture(gl.TEXTURE0);
      gl.bindTexture(gl.TEXTURE_2D, this.gaussians);
      gl.uniform1i(u.u_gaussians, 0);
      // GLSL matrices are column-major: the columns of R are (w0 w4 w8), (w1 w5 w9), (w2 w6 w10).
      gl.uniformMatrix3fv(u.u_rotation, false, [w[0], w[4], w[8], w[1], w[5], w[9], w[2], w[6], w[10]]);
      gl.uniform3f(u.u_translation, w[3], w[7], w[11]);
      gl.uniform4f(u.u_intrinsics, camera.fx, camera.fy, camera.cx, camera.cy);
      gl.uniform2f(u.u_size, width, height);
      gl.uniform2f(u.u_clip, camera.near, camera.far);
      gl.uniform1f(u.u_height, height);
      gl.bindVertexArray(this.vertexArray);
      gl.drawArraysInstanced(gl.TRIANGLE_STRIP, 0, 4, this.count);
      gl.bindVertexArray(null);
      gl.disable(gl.BLEND);

      gl.bindFramebuffer(gl.FRAMEBUFFER, null);
      gl.viewport(0, 0, width, height);
      gl.useProgram(this.present);
      gl.bindTexture(gl.TEXTURE_2D, this.target.texture);
      gl.uniform1i(gl.getUniformLocation(this.present, "u_image"), 0);
      gl.drawArrays(gl.TRIANGLES, 0, 3);
    }
  }

  return { Renderer };
})();
