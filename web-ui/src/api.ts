// Calls to infer-server's HTTP API (docs/web-protocol.md), with the bearer token the server
// requires (infer-server creates one at start). The page's address as infer-server and
// scripts/up.sh print it carries the token in its fragment (`#token=...`, never sent to a server
// nor written into its logs): it is kept in sessionStorage, so it lives as long as the tab, and
// taken out of the address bar. Without it, the token is asked for once (on a 401).

const TOKEN_KEY = "haptics.token";

export class ApiError extends Error {
  constructor(
    readonly status: number,
    message: string,
  ) {
    super(message);
  }
}

export function getToken(): string | null {
  try {
    return sessionStorage.getItem(TOKEN_KEY);
  } catch {
    return null;
  }
}

export function setToken(token: string | null): void {
  try {
    if (token) sessionStorage.setItem(TOKEN_KEY, token);
    else sessionStorage.removeItem(TOKEN_KEY);
  } catch {
    /* storage disabled: the token then lives only until the page asks again */
  }
}

/**
 * Takes `#token=<token>` from the page's address into the tab's storage and removes it from the
 * address bar (and so from the history, bookmarks and screenshots). Other fragments are left.
 * Runs when this module loads, before any call or socket.
 */
export function takeTokenFromFragment(): void {
  try {
    const hash = location.hash.replace(/^#/, "");
    const parts = hash.split("&");
    const i = parts.findIndex((p) => p.startsWith("token="));
    if (i < 0) return;
    const token = decodeURIComponent(parts[i].slice("token=".length));
    if (token) setToken(token);
    parts.splice(i, 1);
    const rest = parts.join("&");
    history.replaceState(history.state, "", location.pathname + location.search + (rest ? `#${rest}` : ""));
  } catch {
    /* no location or history (a unit test): nothing to take */
  }
}
takeTokenFromFragment();

/**
 * The WebSocket subprotocols that carry the token (a browser cannot set Authorization on a
 * WebSocket): `haptics.v1`, which the server selects, and `haptics-token.<hex of the token>`.
 */
export function wsProtocols(): string[] {
  const token = getToken();
  if (!token) return [];
  const hex = Array.from(new TextEncoder().encode(token), (b) => b.toString(16).padStart(2, "0")).join("");
  return ["haptics.v1", `haptics-token.${hex}`];
}

/** Asks the person for a token; resolves to null when they cancel. Set by the page. */
export type TokenPrompt = (reason: string) => Promise<string | null>;
let askToken: TokenPrompt = async () => null;
export function setTokenPrompt(p: TokenPrompt): void {
  askToken = p;
}

async function readError(res: Response): Promise<string> {
  const text = await res.text().catch(() => "");
  try {
    const o = JSON.parse(text);
    if (o && typeof o.error === "string") return o.error;
  } catch {
    /* not JSON: show the text */
  }
  return text.trim() || `${res.status} ${res.statusText}`;
}

/**
 * One API call with the tab's token. A 401 on a change (`prompt`) asks for the token and
 * retries once; a 401 on a read (status, models: polled, so asking each time would nag) throws,
 * and the page lights its token button instead.
 */
async function call(method: string, path: string, body?: unknown, retried = false, prompt = true): Promise<unknown> {
  const headers: Record<string, string> = { Accept: "application/json" };
  const token = getToken();
  if (token) headers.Authorization = `Bearer ${token}`;
  if (body !== undefined) headers["Content-Type"] = "application/json";
  let res: Response;
  try {
    res = await fetch(path, { method, headers, body: body === undefined ? undefined : JSON.stringify(body), cache: "no-store" });
  } catch (e) {
    throw new ApiError(0, `server unreachable (${(e as Error).message})`);
  }
  if (res.status === 401 && !retried && prompt) {
    const t = await askToken(token ? "The server refused the token. Enter the right one." : "This server needs a token for that.");
    if (t === null) throw new ApiError(401, "a token is needed and none was given");
    setToken(t);
    return call(method, path, body, true);
  }
  if (!res.ok) throw new ApiError(res.status, await readError(res));
  const text = await res.text();
  if (!text) return {};
  try {
    return JSON.parse(text);
  } catch {
    throw new ApiError(res.status, `answer is not JSON: ${text.slice(0, 80)}`);
  }
}

export const api = {
  status: () => call("GET", "/api/status", undefined, false, false),
  models: () => call("GET", "/api/models", undefined, false, false),
  load: (name: string) => call("POST", `/api/models/${encodeURIComponent(name)}/load`),
  activate: (name: string) => call("POST", `/api/models/${encodeURIComponent(name)}/activate`),
  startExperiment: (req: ExperimentRequest) => call("POST", "/api/experiment/start", req),
  stopExperiment: () => call("POST", "/api/experiment/stop"),
};

export interface ExperimentRequest {
  kind: "abstraction" | "reproduction" | "shadow";
  ramp_rate?: number;
  cycles?: number;
  f_max_start?: number;
  f_max_step?: number;
}
