// The frame strip (widgets/show_player.py): one image of target | shadow cells from Python, the selected cell
// framed; a click sends its pixel (in the image's own pixels) to Python, which names the frame and selects it.

function render({ model, el }) {
  const box = document.createElement("div");
  box.className = "frame-strip";
  Object.assign(box.style, { maxHeight: `${model.get("height")}px`, overflowY: "auto", display: "inline-block" });
  const canvas = document.createElement("canvas");
  Object.assign(canvas.style, { cursor: "pointer", maxWidth: "100%" });
  box.append(canvas);
  el.append(box);
  let picture = null;
  let generation = 0;

  function draw() {
    if (!picture) return;
    canvas.width = picture.width;
    canvas.height = picture.height;
    const ctx = canvas.getContext("2d");
    ctx.drawImage(picture, 0, 0);
    const b = model.get("boxes")[model.get("selected")];
    if (b) {
      ctx.strokeStyle = "#1565c0";
      ctx.lineWidth = 3;
      ctx.strokeRect(b[0] + 1.5, b[1] + 1.5, b[2] - 3, b[3] - 3);
    }
  }

  async function load() {
    const mine = ++generation;
    const png = model.get("image");
    const bitmap = png && png.byteLength ? await createImageBitmap(new Blob([png], { type: "image/png" })) : null;
    if (mine !== generation) return;
    picture = bitmap;
    draw();
    const b = model.get("boxes")[model.get("selected")];
    if (b) {
      const scale = canvas.getBoundingClientRect().height / Math.max(1, canvas.height) || 1;
      const top = b[1] * scale, bottom = (b[1] + b[3]) * scale;
      if (top < box.scrollTop || bottom > box.scrollTop + box.clientHeight) box.scrollTop = top;
    }
  }

  canvas.addEventListener("click", (ev) => {
    const r = canvas.getBoundingClientRect();
    const x = ((ev.clientX - r.left) * canvas.width) / Math.max(1, r.width);
    const y = ((ev.clientY - r.top) * canvas.height) / Math.max(1, r.height);
    model.send({ type: "click", x, y });
  });
  model.on("change:image", load);
  model.on("change:selected", draw);
  load();
  return () => {
    generation += 1;
  };
}

export default { render };
