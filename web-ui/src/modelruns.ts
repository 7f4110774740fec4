// Which model drew each point. Every telemetry bucket carries the min and max of the `model_id`
// of its steps (the id in the inference server's answer that the loop rendered; 0 where no
// model's answer was used). Consecutive plotted columns with one id form a run; a column whose
// min and max differ holds a swap. The names come from the server's model list and status, and
// are kept after a swap, so the history stays labelled with the model that drew it.
import type { ModelInfo } from "./protocol";
import type { Columns } from "./store";

export interface ModelRun {
  /** Time of the run's first column, and of the column after its last (the view's end for the last). */
  t0: number;
  t1: number;
  /** The model's id; null where one column holds more than one (a swap inside it). */
  id: number | null;
}

/**
 * The runs of series `s` (model_id) in the columns the time plots draw. A column without data
 * (the loop was gone) ends a run and starts none, so the gap stays visible.
 */
export function modelRuns(cols: Columns, s: number, tEnd: number): ModelRun[] {
  const runs: ModelRun[] = [];
  const lo = cols.min[s];
  const hi = cols.max[s];
  let open: ModelRun | null = null;
  for (let i = 0; i < cols.t.length; i++) {
    const a = lo[i];
    const b = hi[i];
    if (open) open.t1 = cols.t[i];
    if (a === null || b === null) {
      open = null;
      continue;
    }
    const id = a === b ? a : null;
    if (open && open.id === id) continue;
    open = { t0: cols.t[i], t1: tEnd, id };
    runs.push(open);
  }
  if (open) open.t1 = tEnd;
  return runs;
}

/** Names of model ids as the server reported them; an id once named keeps its name. */
export class ModelNames {
  private readonly names = new Map<number, string>();

  /** From `/api/models` and the status's `active_model`. */
  learn(models: (ModelInfo | null | undefined)[]): void {
    for (const m of models) if (m && typeof m.model_id === "number" && m.model_id > 0) this.names.set(m.model_id, m.name);
  }

  name(id: number | null): string {
    if (id === null) return "swap";
    if (id === 0) return "no model";
    return this.names.get(id) ?? `model #${id}`;
  }
}
