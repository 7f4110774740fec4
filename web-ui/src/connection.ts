// The telemetry WebSocket, reopened with exponential backoff (and jitter, so many tabs do not
// reconnect in step) whenever it closes, so the page recovers from a server restart on its own.

export type ConnState = "connecting" | "open" | "closed";

export interface ConnEvents {
  onBinary(buf: ArrayBuffer): void;
  onText(text: string): void;
  onState(state: ConnState, info: { retryInMs?: number; attempt: number }): void;
}

export class TelemetryConnection {
  private ws: WebSocket | null = null;
  private attempt = 0;
  private timer: number | undefined;
  private stopped = false;
  readonly minDelayMs = 250;
  readonly maxDelayMs = 5000;

  constructor(
    /** The address, asked again on each (re)open (it carries the rate the page wants now). */
    private readonly url: string | (() => string),
    private readonly ev: ConnEvents,
    /** Subprotocols offered on each (re)open: they carry the token when the server needs one. */
    private readonly protocols: () => string[] = () => [],
  ) {}

  start(): void {
    this.stopped = false;
    this.open();
  }

  /** Reconnect now (the "retry now" button), cancelling a pending backoff. */
  retryNow(): void {
    if (this.ws && this.ws.readyState <= WebSocket.OPEN) return;
    window.clearTimeout(this.timer);
    this.open();
  }

  /** Sends a text frame if the socket is open (dropped otherwise: the next open's address says it). */
  send(text: string): void {
    if (this.ws && this.ws.readyState === WebSocket.OPEN) this.ws.send(text);
  }

  private open(): void {
    this.ev.onState("connecting", { attempt: this.attempt });
    let ws: WebSocket;
    try {
      const protocols = this.protocols();
      const url = typeof this.url === "string" ? this.url : this.url();
      ws = protocols.length ? new WebSocket(url, protocols) : new WebSocket(url);
    } catch {
      this.scheduleRetry();
      return;
    }
    ws.binaryType = "arraybuffer";
    this.ws = ws;
    ws.onopen = () => {
      this.attempt = 0;
      this.ev.onState("open", { attempt: 0 });
    };
    ws.onmessage = (m: MessageEvent) => {
      if (typeof m.data === "string") this.ev.onText(m.data);
      else this.ev.onBinary(m.data as ArrayBuffer);
    };
    ws.onclose = () => {
      if (this.ws !== ws) return;
      this.ws = null;
      if (!this.stopped) this.scheduleRetry();
    };
    ws.onerror = () => {
      /* onclose follows and schedules the retry */
    };
  }

  private scheduleRetry(): void {
    const base = Math.min(this.maxDelayMs, this.minDelayMs * 2 ** this.attempt);
    const delay = Math.round(base * (0.8 + 0.4 * Math.random()));
    this.attempt++;
    this.ev.onState("closed", { retryInMs: delay, attempt: this.attempt });
    window.clearTimeout(this.timer);
    this.timer = window.setTimeout(() => this.open(), delay);
  }
}
