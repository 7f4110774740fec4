// The synchronized time plots (uPlot). Every signal is drawn as its min and its max per column
// with the band between them filled, so a one-step force spike stays visible at any zoom.
import uPlot from "uplot";
import type { Columns } from "./store";

export interface Signal {
  /** Index of the series in the telemetry frame. */
  series: number;
  label: string;
  /** Name in the cursor readout. */
  short: string;
  unit: string;
  color: string;
  /** "y" (left axis) or "y2" (right axis). */
  scale?: "y" | "y2";
  dash?: number[];
  /** Hidden until switched on. */
  hidden?: boolean;
}

export interface PlotDef {
  id: string;
  title: string;
  yLabel: string;
  y2Label?: string;
  signals: Signal[];
  height: number;
}

export interface TimePlotHooks {
  /** The person dragged over [t0, t1]: zoom there. */
  onZoom(t0: number, t1: number): void;
  /** Double-click: back to the live window. */
  onResetZoom(): void;
  /** Mouse wheel at time t: zoom in (dir < 0) or out (dir > 0) around t; with shift, pan. */
  onWheel(t: number, dir: number, pan: boolean): void;
  /** Text added to the cursor readout for column `i` of `cols` (e.g. the model that drew it). */
  readoutExtra?(cols: Columns, i: number): string;
}

function alpha(hex: string, a: number): string {
  const n = parseInt(hex.slice(1), 16);
  return `rgba(${(n >> 16) & 255},${(n >> 8) & 255},${n & 255},${a})`;
}

function fmtTime(v: number, span: number): string {
  const d = span < 0.05 ? 4 : span < 0.5 ? 3 : span < 5 ? 2 : span < 60 ? 1 : 0;
  return v.toFixed(d);
}

export class TimePlot {
  readonly u: uPlot;
  private range: [number, number] = [0, 1];
  private readonly visible: boolean[];
  /** Last data handed to uPlot, for the test hook. */
  last: Columns | null = null;
  private readonly readoutExtra: TimePlotHooks["readoutExtra"];

  constructor(
    readonly def: PlotDef,
    container: HTMLElement,
    syncKey: string,
    hooks: TimePlotHooks,
    private readonly readout: HTMLElement | null = null,
  ) {
    this.visible = def.signals.map((s) => !s.hidden);
    this.readoutExtra = hooks.readoutExtra;
    const series: uPlot.Series[] = [{ label: "t (s)" }];
    for (const [k, sig] of def.signals.entries()) {
      const common = {
        stroke: sig.color,
        width: 1.25,
        scale: sig.scale ?? "y",
        dash: sig.dash,
        show: this.visible[k],
        points: { show: false },
        spanGaps: false,
      };
      series.push({ ...common, label: `${sig.label} max` });
      series.push({ ...common, label: `${sig.label} min` });
    }
    const axes: uPlot.Axis[] = [
      {
        label: "device time (s)",
        labelSize: 18,
        size: 38,
        stroke: "#1f2937",
        grid: { stroke: "#e5e7eb", width: 1 },
        ticks: { stroke: "#9ca3af", width: 1 },
        values: (u, vals) => {
          const span = (u.scales.x.max ?? 1) - (u.scales.x.min ?? 0);
          return vals.map((v) => fmtTime(v, span));
        },
        font: "12px system-ui, sans-serif",
        labelFont: "12px system-ui, sans-serif",
      },
      {
        label: def.yLabel,
        labelSize: 18,
        size: 56,
        scale: "y",
        stroke: "#1f2937",
        grid: { stroke: "#e5e7eb", width: 1 },
        ticks: { stroke: "#9ca3af", width: 1 },
        font: "12px system-ui, sans-serif",
        labelFont: "12px system-ui, sans-serif",
      },
    ];
    const scales: uPlot.Scales = {
      x: { time: false, range: () => this.range },
      y: { range: (_u, min, max) => padRange(min, max) },
    };
    if (def.y2Label) {
      axes.push({
        label: def.y2Label,
        labelSize: 18,
        size: 60,
        side: 1,
        scale: "y2",
        stroke: "#1f2937",
        grid: { show: false },
        ticks: { stroke: "#9ca3af", width: 1 },
        font: "12px system-ui, sans-serif",
        labelFont: "12px system-ui, sans-serif",
      });
      scales.y2 = { range: (_u, min, max) => padRange(min, max) };
    }
    const opts: uPlot.Options = {
      width: Math.max(300, container.clientWidth),
      height: def.height,
      series,
      axes,
      scales,
      legend: { show: false },
      bands: this.bands(),
      cursor: {
        sync: { key: syncKey, setSeries: false },
        drag: { x: true, y: false, setScale: false },
        points: { show: false },
      },
      hooks: {
        setSelect: [
          (u) => {
            if (u.select.width < 4) return;
            const t0 = u.posToVal(u.select.left, "x");
            const t1 = u.posToVal(u.select.left + u.select.width, "x");
            u.setSelect({ left: 0, top: 0, width: 0, height: 0 }, false);
            hooks.onZoom(t0, t1);
          },
        ],
        ready: [
          (u) => {
            u.over.addEventListener("dblclick", () => hooks.onResetZoom());
            u.over.addEventListener(
              "wheel",
              (e) => {
                e.preventDefault();
                hooks.onWheel(u.posToVal(e.offsetX, "x"), Math.sign(e.deltaY || e.deltaX), e.shiftKey || Math.abs(e.deltaX) > Math.abs(e.deltaY));
              },
              { passive: false },
            );
          },
        ],
        // The values under the cursor (synchronised across the plots), as PlotJuggler shows them.
        setCursor: [(u) => this.showReadout(u)],
      },
    };
    this.u = new uPlot(opts, emptyData(def.signals.length), container);
  }

  private showReadout(u: uPlot): void {
    const el = this.readout;
    if (!el) return;
    const i = u.cursor.idx;
    const xs = u.data[0] as ArrayLike<number>;
    if (i === null || i === undefined || i >= xs.length) {
      el.textContent = "";
      return;
    }
    const parts = [`t ${xs[i].toFixed(3)} s`];
    this.def.signals.forEach((sig, k) => {
      if (!this.visible[k]) return;
      const hi = (u.data[1 + 2 * k] as ArrayLike<number | null>)[i];
      const lo = (u.data[2 + 2 * k] as ArrayLike<number | null>)[i];
      if (hi === null || lo === null || hi === undefined || lo === undefined) return;
      const a = fmtVal(lo);
      const b = fmtVal(hi);
      const v = a === b ? a : `${a}…${b}`;
      parts.push(`${sig.short} ${v} ${sig.unit}`);
    });
    const extra = this.last && this.readoutExtra ? this.readoutExtra(this.last, i) : "";
    if (extra) parts.push(extra);
    el.textContent = parts.join(" · ");
    el.title = el.textContent;
  }

  private bands(): uPlot.Band[] {
    const out: uPlot.Band[] = [];
    this.def.signals.forEach((sig, k) => {
      if (!this.visible[k]) return;
      out.push({ series: [1 + 2 * k, 2 + 2 * k], fill: alpha(sig.color, 0.18) });
    });
    return out;
  }

  isVisible(k: number): boolean {
    return this.visible[k];
  }

  setVisible(k: number, show: boolean): void {
    this.visible[k] = show;
    this.u.batch(() => {
      this.u.setSeries(1 + 2 * k, { show });
      this.u.setSeries(2 + 2 * k, { show });
      this.u.delBand(null);
      for (const b of this.bands()) this.u.addBand(b);
    });
    this.u.redraw();
  }

  setSize(width: number, height = this.def.height): void {
    if (Math.abs(width - this.u.width) >= 1 || Math.abs(height - this.u.height) >= 1) this.u.setSize({ width, height });
  }

  update(cols: Columns, t0: number, t1: number): void {
    this.range = [t0, t1];
    this.last = cols;
    const data: uPlot.AlignedData = [cols.t] as unknown as uPlot.AlignedData;
    const d = data as unknown as (number | null)[][];
    for (const sig of this.def.signals) {
      d.push(cols.max[sig.series], cols.min[sig.series]);
    }
    // batch() draws now rather than in a microtask, so the page's draw-time figure is honest.
    this.u.batch(() => this.u.setData(data, true));
  }
}

function fmtVal(v: number): string {
  const a = Math.abs(v);
  return v.toFixed(a >= 100 ? 0 : a >= 10 ? 1 : a >= 0.1 ? 2 : 4);
}

function emptyData(nSignals: number): uPlot.AlignedData {
  const d: number[][] = [[]];
  for (let k = 0; k < nSignals * 2; k++) d.push([]);
  return d as unknown as uPlot.AlignedData;
}

/** Y range with a little headroom, and never a zero-height range (a flat line stays centred). */
function padRange(min: number | null, max: number | null): uPlot.Range.MinMax {
  if (min === null || max === null || !Number.isFinite(min) || !Number.isFinite(max)) return [-1, 1];
  if (max - min < 1e-9) {
    const c = (min + max) / 2;
    const h = Math.max(Math.abs(c) * 0.1, 0.5);
    return [c - h, c + h];
  }
  const pad = (max - min) * 0.06;
  return [min - pad, max + pad];
}
