// A small time-series chart on a 2D canvas: the last `windowSeconds` of one
// or more series, on a linear or a log10 y axis. No dependencies.

export class Chart {
  /**
   * @param {HTMLCanvasElement} canvas
   * @param {{series: {name: string, color: string}[], log?: boolean,
   *          min?: number, max?: number, unit?: string, windowSeconds?: number}} options
   *   On a log axis `min` is the floor: smaller values (0 = converged) are
   *   drawn at it.
   */
  constructor(canvas, options) {
    this.canvas = canvas;
    this.ctx = canvas.getContext('2d');
    this.series = options.series;
    this.log = options.log ?? false;
    this.min = options.min ?? 0;
    this.max = options.max ?? null;
    this.unit = options.unit ?? '';
    this.windowSeconds = options.windowSeconds ?? 60;
    /** Points as [t seconds, ...values], oldest first. */
    this.points = [];
    this.maxPoints = 2000;
    this.dirty = true;
  }

  /** Adds one point (one value per series) at time `t` in seconds. */
  push(t, values) {
    this.points.push([t, ...values]);
    if (this.points.length > this.maxPoints) this.points.splice(0, this.points.length - this.maxPoints);
    this.dirty = true;
  }

  clear() {
    this.points = [];
    this.dirty = true;
  }

  /** Redraws if anything changed since the last draw. */
  draw() {
    if (!this.dirty) return;
    this.dirty = false;
    const { canvas, ctx } = this;
    const dpr = window.devicePixelRatio || 1;
    const cssW = canvas.clientWidth || 300;
    const cssH = canvas.clientHeight || 150;
    if (canvas.width !== Math.round(cssW * dpr) || canvas.height !== Math.round(cssH * dpr)) {
      canvas.width = Math.round(cssW * dpr);
      canvas.height = Math.round(cssH * dpr);
    }
    ctx.setTransform(dpr, 0, 0, dpr, 0, 0);
    ctx.clearRect(0, 0, cssW, cssH);
    const left = 46;
    const right = 8;
    const top = 8;
    const bottom = 18;
    const w = cssW - left - right;
    const h = cssH - top - bottom;

    const now = this.points.length ? this.points[this.points.length - 1][0] : 0;
    const t0 = now - this.windowSeconds;
    const visible = this.points.filter((p) => p[0] >= t0);

    // Y range.
    let lo;
    let hi;
    if (this.log) {
      lo = Math.log10(this.min);
      hi = 0;
      for (const p of visible) {
        for (const v of p.slice(1)) if (v > 0) hi = Math.max(hi, Math.ceil(Math.log10(v)));
      }
    } else {
      lo = this.min;
      hi = this.max ?? 1;
      for (const p of visible) for (const v of p.slice(1)) if (Number.isFinite(v)) hi = Math.max(hi, v * 1.1);
    }
    const yOf = (v) => {
      const u = this.log ? Math.log10(Math.max(v, this.min)) : v;
      return top + h - ((u - lo) / (hi - lo || 1)) * h;
    };
    const xOf = (t) => left + ((t - t0) / this.windowSeconds) * w;

    // Grid and labels.
    ctx.font = '10px system-ui, sans-serif';
    ctx.fillStyle = '#8b93a7';
    ctx.strokeStyle = '#2a3142';
    ctx.lineWidth = 1;
    ctx.textAlign = 'right';
    ctx.textBaseline = 'middle';
    const ticks = [];
    if (this.log) {
      for (let e = Math.floor(lo); e <= hi; e++) ticks.push([10 ** e, `1e${e}`]);
    } else {
      const step = niceStep((hi - lo) / 4);
      for (let v = lo; v <= hi + 1e-9; v += step) ticks.push([v, `${+v.toFixed(2)}${this.unit}`]);
    }
    for (const [v, label] of ticks) {
      const y = Math.round(yOf(v)) + 0.5;
      ctx.beginPath();
      ctx.moveTo(left, y);
      ctx.lineTo(left + w, y);
      ctx.stroke();
      ctx.fillText(label, left - 4, y);
    }
    ctx.textAlign = 'center';
    ctx.textBaseline = 'top';
    for (let s = 0; s <= this.windowSeconds; s += this.windowSeconds / 4) {
      ctx.fillText(s === this.windowSeconds ? 'now' : `-${this.windowSeconds - s}s`, xOf(t0 + s), top + h + 4);
    }

    // Series.
    this.series.forEach((series, i) => {
      ctx.strokeStyle = series.color;
      ctx.lineWidth = 1.5;
      ctx.beginPath();
      let started = false;
      for (const p of visible) {
        const v = p[i + 1];
        if (!Number.isFinite(v)) continue;
        const x = xOf(p[0]);
        const y = yOf(v);
        if (started) ctx.lineTo(x, y);
        else ctx.moveTo(x, y);
        started = true;
      }
      ctx.stroke();
      if (visible.length) {
        const last = visible[visible.length - 1];
        ctx.fillStyle = series.color;
        ctx.beginPath();
        ctx.arc(xOf(last[0]), yOf(last[i + 1]), 2.5, 0, Math.PI * 2);
        ctx.fill();
      }
    });
  }
}

/** 1, 2 or 5 times a power of ten, at least `raw`. */
function niceStep(raw) {
  if (!(raw > 0)) return 1;
  const p = 10 ** Math.floor(Math.log10(raw));
  for (const m of [1, 2, 5, 10]) if (m * p >= raw) return m * p;
  return 10 * p;
}
