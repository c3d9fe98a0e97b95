// The rig scene (widgets/scene_snapshot.py): each meshcat snapshot is a whole page in an iframe of its own. A new
// one loads transparent over the one on show and takes its place only once it has loaded and drawn, so the scene
// is never meshcat's empty default scene while a page loads. A snapshot that arrives while one loads waits for it
// (only the newest waits), then loads in turn.

const DRAWN_FRAMES = 6; // animation frames of the new page after its load event: meshcat's commands replayed, drawn
const DRAWN_MS = 300; // and at least this long after it (its textures decoded)

function render({ model, el }) {
  const box = document.createElement("div");
  box.className = "scene-snapshot";
  const height = () => `${model.get("height")}px`;
  Object.assign(box.style, { position: "relative", width: "100%", height: height(), overflow: "hidden", resize: "vertical" });
  el.append(box);
  let shown = null; // the iframe on show
  let loading = null; // the iframe loading over it
  let waiting = null; // the newest snapshot that arrived while one loads
  let alive = true;

  function afterFrames(win, n, done) {
    if (!alive || n <= 0 || !win) return done();
    win.requestAnimationFrame(() => afterFrames(win, n - 1, done));
  }

  function reveal(frame) {
    if (!alive || loading !== frame) return;
    Object.assign(frame.style, { opacity: "1", pointerEvents: "auto" });
    if (shown) shown.remove();
    shown = frame;
    loading = null;
    if (waiting !== null) {
      const page = waiting;
      waiting = null;
      load(page);
    }
  }

  function load(page) {
    const frame = document.createElement("iframe");
    Object.assign(frame.style, { position: "absolute", inset: "0", width: "100%", height: "100%", border: "none",
                                 opacity: "0", pointerEvents: "none" });
    frame.addEventListener("load", () => {
      const started = performance.now();
      afterFrames(frame.contentWindow, DRAWN_FRAMES, () =>
        setTimeout(() => reveal(frame), Math.max(0, DRAWN_MS - (performance.now() - started))));
    }, { once: true });
    loading = frame;
    frame.srcdoc = page;
    box.append(frame); // after the one on show: over it, transparent until it is drawn
  }

  function update() {
    const page = model.get("page");
    if (!page) {
      for (const f of [shown, loading]) if (f) f.remove();
      shown = loading = waiting = null;
      return;
    }
    if (loading) waiting = page;
    else load(page);
  }

  model.on("change:page", update);
  model.on("change:height", () => { box.style.height = height(); });
  update();
  return () => { alive = false; };
}

export default { render };
