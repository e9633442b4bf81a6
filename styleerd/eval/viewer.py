"""A self-contained HTML page that plays motions side by side (canvas 2D, no network access):
bones drawn as oriented plates with a marked front edge (so a bone rolled about itself shows),
a floor grid that shows foot sliding, play/pause, frame slider, view angle."""

from __future__ import annotations

import html
import json
from pathlib import Path

import numpy as np

from styleerd.atomic import atomic_write_text
from styleerd.motion import quat
from styleerd.motion.kinematics import bone_fronts, forward_kinematics
from styleerd.motion.motion import Motion
from styleerd.motion.resample import resample

_PAGE = """<!doctype html>
<html lang="en"><head><meta charset="utf-8"><title>__TITLE__</title>
<style>
 body { font: 14px system-ui, sans-serif; margin: 16px; background: #fafafa; color: #222; }
 #controls { display: flex; gap: 16px; align-items: center; flex-wrap: wrap; margin: 8px 0; }
 .grid { display: grid; grid-template-columns: repeat(auto-fill, minmax(260px, 1fr)); gap: 10px; }
 figure { margin: 0; background: #fff; border: 1px solid #ddd; border-radius: 6px; padding: 6px; }
 figcaption { font-weight: 600; margin-bottom: 4px; }
 canvas { width: 100%; height: auto; display: block; }
</style></head><body>
<h2>__TITLE__</h2>
<p>__SUBTITLE__</p>
<div id="controls">
 <button id="play">Pause</button>
 <label>frame <input id="frame" type="range" min="0" value="0" style="width:320px"></label>
 <span id="time"></span>
 <label>view <input id="yaw" type="range" min="-180" max="180" value="35"></label>
</div>
<div class="grid" id="grid"></div>
<script>
const DATA = __DATA__;
const grid = document.getElementById("grid");
const frame = document.getElementById("frame"), yaw = document.getElementById("yaw");
const play = document.getElementById("play"), timeLabel = document.getElementById("time");
const T = Math.min(...DATA.motions.map(m => m.frames.length));
frame.max = T - 1;
const views = DATA.motions.map((m, i) => {
  const fig = document.createElement("figure");
  const cap = document.createElement("figcaption"); cap.textContent = m.label;
  const cv = document.createElement("canvas"); cv.width = 520; cv.height = 560;
  fig.appendChild(cap); fig.appendChild(cv); grid.appendChild(fig);
  const colors = ["#1f77b4", "#d62728", "#2ca02c", "#9467bd", "#ff7f0e", "#8c564b", "#e377c2", "#17becf"];
  return { m, ctx: cv.getContext("2d"), color: colors[i % 8] };
});
function project(p, root, c, s, scale, w, h) {
  const x = p[0] - root[0], z = p[2] - root[2];
  const xr = x * c - z * s, zr = x * s + z * c;
  const elev = 0.25;  // look slightly down onto the floor
  return [w / 2 + xr * scale, h * 0.9 - (p[1] * Math.cos(elev) - zr * Math.sin(elev)) * scale];
}
function draw(t) {
  const a = yaw.value * Math.PI / 180, c = Math.cos(a), s = Math.sin(a);
  for (const v of views) {
    const { ctx, m } = v, W = ctx.canvas.width, H = ctx.canvas.height, P = m.frames[t], root = P[0];
    const scale = H * 0.75 / DATA.height;
    ctx.clearRect(0, 0, W, H);
    const step = DATA.height * 0.25, gx = Math.round(root[0] / step) * step, gz = Math.round(root[2] / step) * step;
    ctx.fillStyle = "#bbb";
    for (let i = -6; i <= 6; i++) for (let k = -6; k <= 6; k++) {
      const q = project([gx + i * step, 0, gz + k * step], root, c, s, scale, W, H);
      ctx.fillRect(q[0] - 1.5, q[1] - 1.5, 3, 3);
    }
    // each bone: a plate from the bone to its front (the parent joint's rest +Z, turned with it),
    // filled pale, its front edge dark: a roll of the bone about itself turns the plate
    const F = m.fronts[t];
    ctx.lineCap = "round"; ctx.lineJoin = "round";
    for (let j = 1; j < m.parents.length; j++) {
      const a = P[m.parents[j]], b = P[j], f = F[j];
      const len = Math.hypot(b[0] - a[0], b[1] - a[1], b[2] - a[2]);
      if (len < 1e-6) continue;
      const w = 0.35 * Math.min(len, DATA.height * 0.12);
      const a2 = [a[0] + f[0] * w, a[1] + f[1] * w, a[2] + f[2] * w];
      const b2 = [b[0] + f[0] * w, b[1] + f[1] * w, b[2] + f[2] * w];
      const q = [a, b, b2, a2].map(x => project(x, root, c, s, scale, W, H));
      ctx.fillStyle = v.color + "55"; ctx.beginPath(); ctx.moveTo(q[0][0], q[0][1]);
      for (const r of q.slice(1)) ctx.lineTo(r[0], r[1]);
      ctx.closePath(); ctx.fill();
      ctx.strokeStyle = v.color; ctx.lineWidth = 5;
      ctx.beginPath(); ctx.moveTo(q[0][0], q[0][1]); ctx.lineTo(q[1][0], q[1][1]); ctx.stroke();
      ctx.strokeStyle = "#222"; ctx.lineWidth = 2;
      ctx.beginPath(); ctx.moveTo(q[3][0], q[3][1]); ctx.lineTo(q[2][0], q[2][1]); ctx.stroke();
    }
    ctx.fillStyle = "#333";
    for (const p of P) {
      const q = project(p, root, c, s, scale, W, H);
      ctx.beginPath(); ctx.arc(q[0], q[1], 3.5, 0, 7); ctx.fill();
    }
  }
  timeLabel.textContent = `${(t / DATA.fps).toFixed(2)} s / ${((T - 1) / DATA.fps).toFixed(2)} s`;
  window.framesDrawn = (window.framesDrawn || 0) + 1;  // for tests
}
let playing = true, t0 = null, start = 0;
function tick(now) {
  // the first animation frame's timestamp can be earlier than performance.now() at load:
  // time starts at the first tick, and the index is kept in [0, T)
  if (t0 === null) t0 = now;
  if (playing) { const t = ((Math.floor(start + (now - t0) / 1000 * DATA.fps) % T) + T) % T; frame.value = t; draw(t); }
  requestAnimationFrame(tick);
}

play.onclick = () => {
  playing = !playing; play.textContent = playing ? "Pause" : "Play"; start = +frame.value; t0 = null;
};
frame.oninput = () => { playing = false; play.textContent = "Play"; draw(+frame.value); };
yaw.oninput = () => draw(+frame.value);
requestAnimationFrame(tick);
</script></body></html>
"""


def _rounded(positions: np.ndarray, height: float) -> list:
    """Positions to a millimetre-scale precision whatever the units (cm, m)."""
    return np.round(positions, max(1, int(np.ceil(-np.log10(height / 2000))))).tolist()


def write_html(
    path: str | Path, motions: list[tuple[str, Motion]], title: str, subtitle: str = "", fps: float = 30.0
) -> None:
    """The page at ``path``: every motion resampled to ``fps``, as global joint positions and
    bone fronts."""
    entries, height = [], 1.0
    for label, motion in motions:
        m = resample(motion, fps) if not np.isclose(motion.fps, fps) else motion
        g_rot, g = forward_kinematics(m.rotations, m.positions, m.skeleton.parents)
        height = max(height, float(np.ptp(g[0, :, 1])))
        entries.append(
            {
                "label": label,
                "parents": m.skeleton.parents.tolist(),
                "frames": _rounded(g, height),
                "fronts": np.round(
                    quat.mul_vec(g_rot[:, np.maximum(m.skeleton.parents, 0)], bone_fronts(m.skeleton)), 2
                ).tolist(),
            }
        )
    data = json.dumps({"fps": fps, "height": height * 1.1, "motions": entries}, separators=(",", ":"))
    page = (
        _PAGE.replace("__TITLE__", html.escape(title))
        .replace("__SUBTITLE__", html.escape(subtitle))
        .replace("__DATA__", data)
    )
    atomic_write_text(Path(path), page)
