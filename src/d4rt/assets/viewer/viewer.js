// d4rt's offline viewer: a small software renderer on a 2D canvas (no WebGL, no libraries, no network).
// Points are splatted into an ImageData with a z-buffer; cameras and tracks are canvas lines on top.
// World coordinates are d4rt's: the OpenCV camera of frame 0 (x right, y down, z forward).
"use strict";
(function () {
  const body = document.body;
  window.addEventListener("error", (e) => { body.dataset.status = "error: " + e.message; });

  const data = JSON.parse(document.getElementById("d4rt-data").textContent);
  function decode(b64, Type) {
    const bin = atob(b64);
    const bytes = new Uint8Array(bin.length);
    for (let i = 0; i < bin.length; i++) bytes[i] = bin.charCodeAt(i);
    return new Type(bytes.buffer);
  }
  const P = decode(data.points, Float32Array);        // M*3, sorted by frame
  const C = decode(data.colors, Uint8Array);          // M*3
  const offsets = data.frame_offsets;                 // T+1: points of frame k are [offsets[k], offsets[k+1])
  const T = data.num_frames;
  const centres = decode(data.camera_centres, Float32Array);  // T*3
  const frusta = decode(data.frusta, Float32Array);  // T*S*2*3
  const segsPerCam = data.frustum_segments;
  const N = data.num_tracks;
  const tracks = decode(data.tracks, Float32Array);  // N*T*3 (NaN where unknown)
  const vis = decode(data.track_visible, Uint8Array); // N*T
  const tcol = decode(data.track_colors, Uint8Array); // N*3
  const TRAIL = 8;

  const canvas = document.getElementById("view");
  const ctx = canvas.getContext("2d");
  const ui = {
    play: document.getElementById("play"), frame: document.getElementById("frame"),
    label: document.getElementById("label"), all: document.getElementById("all"),
    tracks: document.getElementById("showTracks"), cams: document.getElementById("showCams"),
    size: document.getElementById("size"), bar: document.getElementById("bar"),
  };
  ui.frame.max = String(T - 1);

  // ---- orbit camera: yaw about the world's up axis (-y), pitch towards it; looks at `target`.
  const home = { target: data.view_target, yaw: data.view_yaw, pitch: data.view_pitch, distance: data.view_distance };
  let view = Object.assign({}, home, { target: home.target.slice() });
  const FOV = 55 * Math.PI / 180;
  function basis() {
    const cp = Math.cos(view.pitch), sp = Math.sin(view.pitch), cy = Math.cos(view.yaw), sy = Math.sin(view.yaw);
    const fwd = [sy * cp, sp, cy * cp];
    const right = [cy, 0, -sy];  // down x fwd, with down = +y
    const down = [fwd[1] * right[2] - fwd[2] * right[1], fwd[2] * right[0] - fwd[0] * right[2],
                  fwd[0] * right[1] - fwd[1] * right[0]];
    const eye = [0, 1, 2].map((i) => view.target[i] - fwd[i] * view.distance);
    return { fwd, right, down, eye };
  }

  let frame = 0, playing = true, image = null, zbuf = null;
  function resize() {
    canvas.width = Math.max(1, window.innerWidth);
    canvas.height = Math.max(1, window.innerHeight - ui.bar.offsetHeight);
    image = ctx.createImageData(canvas.width, canvas.height);
    zbuf = new Float32Array(canvas.width * canvas.height);
    render();
  }

  function render() {
    const W = canvas.width, H = canvas.height, f = 0.5 * H / Math.tan(FOV / 2);
    const b = basis(), near = 1e-3 * view.distance;
    const pix = new Uint32Array(image.data.buffer);
    pix.fill(0xff1a1614);  // ABGR of #14161a
    zbuf.fill(Infinity);
    const s = Number(ui.size.value), half = Math.floor(s / 2);
    const lo = ui.all.checked ? 0 : offsets[frame], hi = ui.all.checked ? offsets[T] : offsets[frame + 1];
    let drawn = 0;
    for (let i = lo; i < hi; i++) {
      const dx = P[3 * i] - b.eye[0], dy = P[3 * i + 1] - b.eye[1], dz = P[3 * i + 2] - b.eye[2];
      const z = dx * b.fwd[0] + dy * b.fwd[1] + dz * b.fwd[2];
      if (!(z > near)) continue;
      const x = Math.round(f * (dx * b.right[0] + dy * b.right[1] + dz * b.right[2]) / z + W / 2) - half;
      const y = Math.round(f * (dx * b.down[0] + dy * b.down[1] + dz * b.down[2]) / z + H / 2) - half;
      if (x + s <= 0 || y + s <= 0 || x >= W || y >= H) continue;
      const colour = 0xff000000 | (C[3 * i + 2] << 16) | (C[3 * i + 1] << 8) | C[3 * i];
      for (let v = Math.max(0, y); v < Math.min(H, y + s); v++) {
        for (let u = Math.max(0, x); u < Math.min(W, x + s); u++) {
          const k = v * W + u;
          if (z < zbuf[k]) { zbuf[k] = z; pix[k] = colour; }
        }
      }
      drawn++;
    }
    ctx.putImageData(image, 0, 0);

    function toScreen(x, y, z) {
      const dx = x - b.eye[0], dy = y - b.eye[1], dz = z - b.eye[2];
      const d = dx * b.fwd[0] + dy * b.fwd[1] + dz * b.fwd[2];
      if (!(d > near)) return null;
      return [f * (dx * b.right[0] + dy * b.right[1] + dz * b.right[2]) / d + W / 2,
              f * (dx * b.down[0] + dy * b.down[1] + dz * b.down[2]) / d + H / 2];
    }
    function segment(a, c) {
      if (a && c) { ctx.moveTo(a[0], a[1]); ctx.lineTo(c[0], c[1]); }
    }

    if (ui.cams.checked) {
      for (let k = 0; k < T; k++) {
        ctx.beginPath();
        ctx.strokeStyle = k === frame ? "#ff6020" : "rgba(160, 170, 190, 0.35)";
        ctx.lineWidth = k === frame ? 2 : 1;
        for (let j = 0; j < segsPerCam; j++) {
          const o = ((k * segsPerCam + j) * 2) * 3;
          segment(toScreen(frusta[o], frusta[o + 1], frusta[o + 2]), toScreen(frusta[o + 3], frusta[o + 4], frusta[o + 5]));
        }
        ctx.stroke();
      }
      ctx.beginPath();
      ctx.strokeStyle = "rgba(255, 96, 32, 0.6)";
      ctx.lineWidth = 1;
      for (let k = 0; k + 1 < T; k++) {
        segment(toScreen(centres[3 * k], centres[3 * k + 1], centres[3 * k + 2]),
                toScreen(centres[3 * k + 3], centres[3 * k + 4], centres[3 * k + 5]));
      }
      ctx.stroke();
    }

    if (ui.tracks.checked) {
      ctx.lineWidth = 1.5;
      for (let n = 0; n < N; n++) {
        const colour = "rgb(" + tcol[3 * n] + "," + tcol[3 * n + 1] + "," + tcol[3 * n + 2] + ")";
        const at = (k) => (vis[n * T + k] ? toScreen(tracks[(n * T + k) * 3], tracks[(n * T + k) * 3 + 1], tracks[(n * T + k) * 3 + 2]) : null);
        ctx.beginPath();
        ctx.strokeStyle = colour;
        let prev = at(Math.max(0, frame - TRAIL));
        for (let k = Math.max(0, frame - TRAIL) + 1; k <= frame; k++) {
          const cur = at(k);
          segment(prev, cur);
          prev = cur;
        }
        ctx.stroke();
        const now = at(frame);
        if (now) {
          ctx.fillStyle = colour;
          ctx.fillRect(now[0] - 2, now[1] - 2, 4, 4);
        }
      }
    }

    ui.frame.value = String(frame);
    const stamp = data.timestamps ? "  t = " + (data.timestamps[frame] - data.timestamps[0]).toFixed(2) + " s" : "";
    ui.label.textContent = "frame " + frame + " / " + (T - 1) + stamp;
    body.dataset.status = "ready";
    body.dataset.drawnPoints = String(drawn);
  }

  // ---- playback
  let timer = null;
  function setPlaying(on) {
    playing = on;
    ui.play.textContent = on ? "Pause" : "Play";
    if (timer) { clearInterval(timer); timer = null; }
    if (on) timer = setInterval(() => { frame = (frame + 1) % T; render(); }, 1000 / data.fps);
  }
  ui.play.addEventListener("click", () => setPlaying(!playing));
  ui.frame.addEventListener("input", () => { frame = Number(ui.frame.value); render(); });
  for (const el of [ui.all, ui.tracks, ui.cams, ui.size]) el.addEventListener("change", render);
  window.addEventListener("keydown", (e) => {
    if (e.key === " ") { setPlaying(!playing); e.preventDefault(); }
    else if (e.key === "ArrowRight") { frame = Math.min(T - 1, frame + 1); render(); }
    else if (e.key === "ArrowLeft") { frame = Math.max(0, frame - 1); render(); }
  });

  // ---- mouse: orbit, pan, zoom
  let drag = null;
  canvas.addEventListener("contextmenu", (e) => e.preventDefault());
  canvas.addEventListener("mousedown", (e) => { drag = { x: e.clientX, y: e.clientY, pan: e.shiftKey || e.button === 2 }; });
  window.addEventListener("mouseup", () => { drag = null; });
  window.addEventListener("mousemove", (e) => {
    if (!drag) return;
    const dx = e.clientX - drag.x, dy = e.clientY - drag.y;
    drag.x = e.clientX; drag.y = e.clientY;
    if (drag.pan) {
      const b = basis(), step = view.distance / canvas.height;
      for (let i = 0; i < 3; i++) view.target[i] -= (b.right[i] * dx + b.down[i] * dy) * step;
    } else {
      view.yaw -= dx * 0.008;
      view.pitch = Math.max(-1.5, Math.min(1.5, view.pitch + dy * 0.008));
    }
    render();
  });
  canvas.addEventListener("wheel", (e) => {
    view.distance *= Math.exp(e.deltaY * 0.001);
    e.preventDefault();
    render();
  }, { passive: false });
  canvas.addEventListener("dblclick", () => { view = Object.assign({}, home, { target: home.target.slice() }); render(); });

  window.addEventListener("resize", resize);
  resize();
  setPlaying(true);
})();
