// The show preview player (widgets/show_player.py): pre-rendered JPEG frames played in the browser with
// requestAnimationFrame, so the kernel is free while it plays. Play / pause, a scrub slider, loop, speed, a
// timeline (an image from Python) with a playhead that seeks on click or drag. The frame in view goes back to
// Python as `index` (at most ~4 times a second while playing; at once on pause and scrub); `measured_fps` is the
// rate new frames were drawn at while playing.

const SYNC_MS = 250; // the shortest time between two `index` updates sent to Python while playing
const AHEAD = 48; // frames decoded ahead of the one in view (~2 s at 25 fps; a JPEG decodes in ~1 ms)
const KEEP = 160; // decoded frames kept at most (a long show's frames stay compressed until they are near)

function slice(blob, offsets, i) {
  const a = offsets[i], b = offsets[i + 1];
  return new Uint8Array(blob.buffer, blob.byteOffset + a, b - a);
}

async function decode(bytes, type) {
  return await createImageBitmap(bytes instanceof Blob ? bytes : new Blob([bytes], { type }));
}

function element(tag, style, attrs = {}) {
  const e = document.createElement(tag);
  Object.assign(e.style, style);
  for (const [k, v] of Object.entries(attrs)) e[k] = v;
  return e;
}

function render({ model, el }) {
  // flex-start: each row keeps its own width, so the picture never stretches as the label's text changes
  const root = element("div", {
    display: "inline-flex", flexDirection: "column", alignItems: "flex-start", gap: "4px", fontSize: "12px",
  });
  root.className = "show-player";
  const screen = element("canvas", { maxWidth: "100%", background: "#888", imageRendering: "auto" });
  const line = element("canvas", { maxWidth: "100%", cursor: "pointer", height: "24px" });
  const bar = element("div", { display: "flex", alignItems: "center", gap: "6px" });
  const play = element("button", { width: "5em" }, { textContent: "Play" });
  const scrub = element("input", { flex: "1" }, { type: "range", min: 0, max: 0, step: 1, value: 0 });
  const loop = element("input", {}, { type: "checkbox" });
  const speed = element("select", {});
  for (const s of [0.25, 0.5, 1, 1.5, 2]) speed.append(element("option", {}, { value: s, textContent: `${s}×` }));
  const label = element("span", {
    display: "inline-block", width: "18em", whiteSpace: "nowrap", overflow: "hidden", fontFamily: "monospace",
  }); // a fixed width: the bar does not change size as the time ticks
  const loopLabel = element("label", {});
  loopLabel.append(loop, " loop");
  bar.append(play, scrub, loopLabel, speed, label);
  root.append(screen, line, bar);
  el.append(root);

  let blobs = []; // every frame's JPEG
  const cache = new Map(); // frame → its decoded ImageBitmap (a window around the frame in view)
  const pending = new Set();
  let wanted = -1; // the frame to paint once it is decoded
  let timeline = null;
  let generation = 0;
  let pos = 0; // frame position (float) while playing
  let shown = -1;
  let raf = 0, last = 0, lastSync = 0, drawn = 0, since = 0;

  const count = () => blobs.length;

  function evict(center) {
    const n = count();
    if (cache.size <= KEEP) return;
    for (const [j, b] of cache) {
      const ahead = (j - center + n) % n;
      if (ahead >= AHEAD && n - ahead > KEEP - AHEAD) {
        b.close();
        cache.delete(j);
      }
    }
  }

  function want(i) {
    // decode frame i and the frames after it (wrapping round when looping), in the background
    const n = count(), mine = generation;
    for (let k = 0; k < Math.min(AHEAD, n); k++) {
      let j = i + k;
      if (j >= n) {
        if (!model.get("loop")) break;
        j -= n;
      }
      if (cache.has(j) || pending.has(j)) continue;
      pending.add(j);
      decode(blobs[j]).then((b) => {
        pending.delete(j);
        if (mine !== generation) return b.close();
        cache.set(j, b);
        if (j === wanted) paint(j);
        evict(shown);
      });
    }
  }

  function paint(i) {
    const b = cache.get(i);
    if (!b) return;
    if (screen.width !== b.width || screen.height !== b.height) {
      screen.width = b.width;
      screen.height = b.height;
      bar.style.width = `${b.width}px`; // the controls as wide as the picture (the slider takes what is left)
      drawLine(shown);
    }
    screen.getContext("2d").drawImage(b, 0, 0);
    root.dataset.painted = String(i);
    wanted = -1;
    drawn += 1;
  }
  const times = () => model.get("times");

  function drawLine(i) {
    const ctx = line.getContext("2d");
    const w = (line.width = screen.width || 480), h = (line.height = 24);
    ctx.fillStyle = "#f8f8f8";
    ctx.fillRect(0, 0, w, h);
    if (timeline) ctx.drawImage(timeline, 0, 0, w, h);
    const t = times(), start = model.get("start"), end = model.get("end");
    if (i >= 0 && i < t.length && end > start) {
      const x = Math.round(((t[i] - start) / (end - start)) * (w - 1));
      ctx.fillStyle = "#1565c0";
      ctx.fillRect(x - 1, 0, 3, h);
    }
  }

  function draw(i) {
    if (!count()) return;
    i = Math.max(0, Math.min(count() - 1, i));
    shown = wanted = i;
    root.dataset.frame = String(i);
    want(i);
    paint(i);
    scrub.value = i;
    const t = times()[i] ?? 0;
    const rate = model.get("measured_fps");
    label.textContent = `${t.toFixed(2)} s  frame ${i + 1}/${count()}` + (rate ? `  ${rate} fps` : "");
    drawLine(i);
  }

  function send(i, force) {
    const now = performance.now();
    if (!force && now - lastSync < SYNC_MS) return;
    lastSync = now;
    if (model.get("index") !== i) {
      model.set("index", i);
      model.save_changes();
    }
  }

  function tick(now) {
    const dt = (now - last) / 1000;
    last = now;
    pos += dt * model.get("fps") * model.get("speed");
    if (pos >= count()) {
      if (model.get("loop")) pos %= count();
      else {
        pos = count() - 1;
        draw(count() - 1);
        setPlaying(false);
        return;
      }
    }
    const i = Math.floor(pos);
    if (i !== shown) {
      draw(i);
      send(i, false);
    }
    if (now - since >= 1000) {
      root.dataset.fps = String((drawn * 1000) / (now - since));
      model.set("measured_fps", Math.round((drawn * 1000) / (now - since)));
      model.save_changes();
      drawn = 0;
      since = now;
    }
    raf = requestAnimationFrame(tick);
  }

  function setPlaying(on) {
    cancelAnimationFrame(raf);
    raf = 0;
    play.textContent = on ? "Pause" : "Play";
    if (on && count()) {
      if (shown >= count() - 1 && !model.get("loop")) pos = 0;
      last = since = performance.now();
      drawn = 0;
      raf = requestAnimationFrame(tick);
    } else send(Math.max(shown, 0), true);
    if (model.get("playing") !== on) {
      model.set("playing", on);
      model.save_changes();
    }
  }

  function seek(i, force = true) {
    pos = i;
    draw(i);
    send(shown, force); // a drag sends at most ~4 times a second, its end at once
  }

  async function load() {
    const mine = ++generation;
    const blob = model.get("frames"), offsets = model.get("offsets");
    const png = model.get("timeline");
    const line_ = png && png.byteLength ? await decode(png, "image/png") : null;
    if (mine !== generation) return;
    for (const b of cache.values()) b.close();
    cache.clear();
    pending.clear();
    blobs = [];
    if (blob && blob.byteLength !== undefined) {
      for (let i = 0; i + 1 < offsets.length; i++) blobs.push(new Blob([slice(blob, offsets, i)], { type: "image/jpeg" }));
    }
    timeline = line_;
    scrub.max = Math.max(0, count() - 1);
    pos = Math.min(model.get("index"), Math.max(0, count() - 1));
    shown = -1;
    draw(Math.floor(pos));
    drawLine(shown);
    if (model.get("playing")) setPlaying(true);
  }

  play.addEventListener("click", () => setPlaying(!raf));
  scrub.addEventListener("input", () => seek(Number(scrub.value), false));
  scrub.addEventListener("change", () => seek(Number(scrub.value)));
  loop.addEventListener("change", () => {
    model.set("loop", loop.checked);
    model.save_changes();
  });
  speed.addEventListener("change", () => {
    model.set("speed", Number(speed.value));
    model.save_changes();
  });
  function fromLine(ev, force) {
    const r = line.getBoundingClientRect();
    const start = model.get("start"), end = model.get("end");
    const t = start + ((ev.clientX - r.left) / Math.max(1, r.width)) * (end - start);
    const ts = times();
    let best = 0;
    for (let i = 0; i < ts.length; i++) if (Math.abs(ts[i] - t) < Math.abs(ts[best] - t)) best = i;
    seek(best, force);
  }
  line.addEventListener("mousedown", (ev) => {
    fromLine(ev, false);
    const move = (e) => fromLine(e, false);
    const up = (e) => {
      fromLine(e, true);
      window.removeEventListener("mousemove", move);
      window.removeEventListener("mouseup", up);
    };
    window.addEventListener("mousemove", move);
    window.addEventListener("mouseup", up);
  });

  const sync = () => {
    loop.checked = model.get("loop");
    speed.value = String(model.get("speed"));
  };
  let queued = false;
  const reload = () => {
    if (queued) return;
    queued = true;
    queueMicrotask(() => {
      queued = false;
      load();
    });
  };
  model.on("change:frames", reload);
  model.on("change:timeline", reload);
  model.on("change:loop", sync);
  model.on("change:speed", sync);
  model.on("change:index", () => {
    const i = model.get("index");
    if (i === shown) return;
    if (raf) pos = i;
    else seek(i);
  });
  model.on("change:playing", () => {
    if (model.get("playing") !== !!raf) setPlaying(model.get("playing"));
  });
  sync();
  load();
  return () => {
    cancelAnimationFrame(raf);
    generation += 1;
    for (const b of cache.values()) b.close();
    cache.clear();
  };
}

export default { render };
