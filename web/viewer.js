// The page: loads the avatar, plays the motion (play/pause, frame slider), orbits the camera about the body (drag to
// turn, wheel to zoom) and shows per-frame timings. ?frame=K starts paused at frame K; &camera=render shows the still
// camera that `sfgs render --camera fixed` uses, at its size, without controls (docs/web_viewer.md).
"use strict";

(() => {
  const canvas = document.getElementById("view");
  const message = document.getElementById("message");
  const playButton = document.getElementById("play");
  const slider = document.getElementById("frame");
  const status = document.getElementById("status");
  const params = new URLSearchParams(window.location.search);

  function fail(text) {
    document.body.classList.add("failed");
    message.textContent = text;
    document.title = "sfgs avatar: " + text;
  }

  if (typeof sfgsExport === "undefined") {
    fail("No avatar data here: open the index.html that `sfgs export --web` wrote.");
    return;
  }
  const manifest = sfgsExport;
  const still = params.get("camera") === "render";
  if (params.has("camera") && !still) {
    fail(`unknown camera '${params.get("camera")}' (the only named camera is 'render')`);
    return;
  }
  let avatar, renderer, sorter;
  try {
    avatar = new SfgsPose.Avatar(manifest, sfgsData);
    renderer = new SfgsRenderer.Renderer(canvas, manifest.gaussians, manifest.splatting, manifest.background);
    sorter = new SfgsSort.DepthSorter(manifest.gaussians);
  } catch (error) {
    fail(error.message);
    return;
  }

  const exported = manifest.camera;
  const focalPerHeight = exported.fy / exported.height;
  const target = exported.target;
  // The orbit starts where the exported camera stands: its centre is -R^T t of world_to_camera = [R | t].
  const w = exported.world_to_camera;
  const eye = [0, 1, 2].map((c) => -(w[c] * w[3] + w[4 + c] * w[7] + w[8 + c] * w[11]));
  const offset = eye.map((v, c) => v - target[c]);
  const orbit = {
    distance: Math.hypot(...offset),
    yaw: Math.atan2(offset[0], offset[2]),
    pitch: Math.asin(offset[1] / Math.hypot(...offset)),
  };
  const PITCH_LIMIT = 1.5;  // radians: short of straight up or down, where the look-at has no right vector

  // csrc/cli/motion_source.cpp's look_at_camera: x right, y down, z forward, world +Y up.
  function orbitCamera(width, height) {
    const e = [target[0] + orbit.distance * Math.cos(orbit.pitch) * Math.sin(orbit.yaw),
               target[1] + orbit.distance * Math.sin(orbit.pitch),
               target[2] + orbit.distance * Math.cos(orbit.pitch) * Math.cos(orbit.yaw)];
    const fwd = target.map((v, c) => v - e[c]);
    const fn = Math.hypot(...fwd);
    fwd.forEach((v, c) => { fwd[c] = v / fn; });
    const rn = Math.hypot(fwd[2], fwd[0]);
    const right = [-fwd[2] / rn, 0, fwd[0] / rn];
    const down = [fwd[1] * right[2] - fwd[2] * right[1], fwd[2] * right[0] - fwd[0] * right[2],
                  fwd[0] * right[1] - fwd[1] * right[0]];
    const rows = [right, down, fwd];
    const worldToCamera = [];
    for (const r of rows) worldToCamera.push(r[0], r[1], r[2], -(r[0] * e[0] + r[1] * e[1] + r[2] * e[2]));
    worldToCamera.push(0, 0, 0, 1);
    const focal = focalPerHeight * height;
    return { worldToCamera, fx: focal, fy: focal, cx: width / 2, cy: height / 2, near: exported.near,
             far: exported.far };
  }

  function currentCamera() {
    if (still) {
      return { worldToCamera: exported.world_to_camera, fx: exported.fx, fy: exported.fy, cx: exported.cx,
               cy: exported.cy, near: exported.near, far: exported.far };
    }
    return orbitCamera(canvas.width, canvas.height);
  }

  function fitCanvas() {
    if (still) {
      document.body.classList.add("still");
      canvas.width = exported.width;
      canvas.height = exported.height;
      canvas.style.width = `${exported.width / window.devicePixelRatio}px`;
      canvas.style.height = `${exported.height / window.devicePixelRatio}px`;
      return;
    }
    canvas.width = Math.max(1, Math.round(canvas.clientWidth * window.devicePixelRatio));
    canvas.height = Math.max(1, Math.round(canvas.clientHeight * window.devicePixelRatio));
  }

  const state = {
    frame: Math.min(Math.max(parseInt(params.get("frame") || "0", 10) || 0, 0), manifest.frames - 1),
    playing: !params.has("frame") && manifest.frames > 1,
    posedFrame: -1,   // the frame whose Gaussians the renderer holds
    dirty: true,      // the camera or the frame changed since the last draw
    clock: 0,         // playback position in frames
    lastTime: 0,      // of the last animation frame
    lastDraw: 0,
    timings: { pose: 0, sort: 0, fps: 0 },
  };
  slider.max = String(manifest.frames - 1);

  function draw() {
    let start = performance.now();
    // Frames drawn per second while playing (smoothed): what posing, sorting and splatting together allow.
    if (state.playing && state.lastDraw) {
      state.timings.fps = 0.8 * state.timings.fps + 0.2 * (1000 / (start - state.lastDraw));
    }
    state.lastDraw = start;
    if (state.posedFrame !== state.frame) {
      avatar.pose(state.frame, renderer.texels);
      renderer.uploadGaussians();
      state.posedFrame = state.frame;
      state.timings.pose = performance.now() - start;
      start = performance.now();
    }
    const camera = currentCamera();
    renderer.uploadOrder(sorter.sort(avatar.positions, camera.worldToCamera));
    state.timings.sort = performance.now() - start;
    start = performance.now();
    renderer.draw(camera);
    state.dirty = false;
    slider.value = String(state.frame);
    const t = state.timings;
    status.textContent = `frame ${state.frame + 1}/${manifest.frames} · ${manifest.gaussians} Gaussians · pose ` +
        `${t.pose.toFixed(0)} ms · sort ${t.sort.toFixed(0)} ms` +
        (state.playing ? ` · ${t.fps.toFixed(1)} frames/s` : "");
  }

  function tick(time) {
    const elapsed = state.lastTime ? (time - state.lastTime) / 1000 : 0;
    state.lastTime = time;
    if (state.playing) {
      state.clock = (state.clock + elapsed * manifest.frames_per_second) % manifest.frames;
      const frame = Math.floor(state.clock);
      if (frame !== state.frame) {
        state.frame = frame;
        state.dirty = true;
      }
    }
    if (state.dirty) draw();
    window.requestAnimationFrame(tick);
  }

  function setPlaying(playing) {
    state.playing = playing;
    state.lastDraw = 0;
    state.clock = state.frame;
    playButton.textContent = playing ? "Pause" : "Play";
  }

  function showFrame(frame) {
    state.frame = frame;
    state.clock = frame;
    state.dirty = true;
  }

  fitCanvas();
  setPlaying(state.playing);
  try {
    draw();  // at once, while the page loads: a screenshot taken after loading shows it
  } catch (error) {
    fail(error.message);
    return;
  }
  message.textContent = "";
  document.title = `sfgs avatar: ${manifest.motion}`;
  if (still) return;

  playButton.addEventListener("click", () => setPlaying(!state.playing));
  slider.addEventListener("input", () => {
    setPlaying(false);
    showFrame(parseInt(slider.value, 10));
  });
  window.addEventListener("keydown", (event) => {
    if (event.key === " ") setPlaying(!state.playing);
    else if (event.key === "ArrowRight") showFrame((state.frame + 1) % manifest.frames);
    else if (event.key === "ArrowLeft") showFrame((state.frame + manifest.frames - 1) % manifest.frames);
    else return;
    event.preventDefault();
  });
  let drag = null;
  canvas.addEventListener("pointerdown", (event) => {
    drag = { x: event.clientX, y: event.clientY };
    canvas.setPointerCapture(event.pointerId);
  });
  canvas.addEventListener("pointermove", (event) => {
    if (!drag) return;
    orbit.yaw -= 0.01 * (event.clientX - drag.x);
    orbit.pitch = Math.min(PITCH_LIMIT, Math.max(-PITCH_LIMIT, orbit.pitch + 0.01 * (event.clientY - drag.y)));
    drag = { x: event.clientX, y: event.clientY };
    state.dirty = true;
  });
  canvas.addEventListener("pointerup", () => { drag = null; });
  canvas.addEventListener("wheel", (event) => {
    event.preventDefault();
    orbit.distance *= Math.exp(0.001 * event.deltaY);
    state.dirty = true;
  }, { passive: false });
  window.addEventListener("resize", () => {
    fitCanvas();
    state.dirty = true;
  });
  window.requestAnimationFrame(tick);
})();
