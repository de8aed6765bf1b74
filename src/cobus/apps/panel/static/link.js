// The page's one WebSocket to the panel: a snapshot, deltas, numbered events, commands.
//
// The state is the latest value of every key. Events are numbered; one that does not follow
// the last means some were lost, so the page asks for a snapshot ("resync") and ignores events
// until it comes. Commands return a promise: resolved with the ack's result, rejected with
// {code, text}. The connection is made again after a loss, with a growing pause.

const params = new URLSearchParams(location.search);
const token = params.get("token") || sessionStorage.getItem("cobus-token") || "";
if (params.get("token")) sessionStorage.setItem("cobus-token", token);

export class Link {
  constructor(handlers) {
    this.handlers = handlers;      // {snapshot(msg), delta(values), event(ev), status(up, text)}
    this.state = {};
    this.info = {};
    this.seq = 0;
    this.syncing = true;
    this.pending = new Map();
    this.nextId = 1;
    this.serverTime = 0;
    this.receivedAt = performance.now();
    this.pause = 500;
    this.token = token;
    this.connect();
  }

  connect() {
    const scheme = location.protocol === "https:" ? "wss" : "ws";
    const query = this.token ? `?token=${encodeURIComponent(this.token)}` : "";
    const ws = new WebSocket(`${scheme}://${location.host}/ws${query}`);
    this.ws = ws;
    ws.onopen = () => {
      this.pause = 500;
      this.opened = true;
      this.handlers.status(true, "connected");
    };
    ws.onmessage = (e) => {
      let msg;
      try {
        msg = JSON.parse(e.data);
      } catch (err) {
        console.warn("cobus panel: a message that is not JSON", err);
        return;
      }
      // one message, or several queued together (in order)
      for (const one of Array.isArray(msg) ? msg : [msg]) this.receive(one);
    };
    ws.onclose = (e) => {
      for (const [, p] of this.pending) p.reject({code: "disconnected", text: "the panel went away"});
      this.pending.clear();
      this.syncing = true;
      const why = e.reason ? `: ${e.reason}` : "";
      if (!this.opened && !this.token) {
        // (refused before it ever opened: a panel reached from elsewhere needs its token)
        this.handlers.status(false, "cannot connect: if this panel was started with a token, " +
          "open the address it printed (with ?token=...); trying again");
      } else {
        this.handlers.status(false, `disconnected${why}; trying again`);
      }
      setTimeout(() => this.connect(), this.pause);
      this.pause = Math.min(this.pause * 2, 5000);
    };
  }

  clock(time) {
    this.serverTime = time;
    this.receivedAt = performance.now();
  }

  // The panel's clock now (seconds, as its events and samples carry it), estimated.
  now() {
    return this.serverTime + (performance.now() - this.receivedAt) / 1000;
  }

  receive(msg) {
    switch (msg.type) {
      case "snapshot":
        this.clock(msg.time);
        this.state = msg.state;
        this.info = msg.info;
        this.seq = msg.seq;
        this.syncing = false;
        this.handlers.snapshot(msg);
        break;
      case "delta":
        this.clock(msg.time);
        Object.assign(this.state, msg.values);
        this.handlers.delta(msg.values);
        break;
      case "event":
        if (this.syncing) return;
        if (msg.seq !== this.seq + 1) {
          this.syncing = true;
          this.ws.send(JSON.stringify({cmd: "resync"}));
          return;
        }
        this.seq = msg.seq;
        this.handlers.event(msg);
        break;
      case "ack":
      case "error": {
        const p = this.pending.get(msg.id);
        if (p === undefined) {
          if (msg.type === "error") this.handlers.error(msg);
          return;
        }
        this.pending.delete(msg.id);
        if (msg.type === "ack") p.resolve(msg.result); else p.reject(msg);
        break;
      }
    }
  }

  // Send a command; a promise of its result.
  command(cmd, args = {}) {
    const id = this.nextId++;
    return new Promise((resolve, reject) => {
      if (this.ws.readyState !== WebSocket.OPEN) {
        reject({code: "disconnected", text: "not connected to the panel"});
        return;
      }
      this.pending.set(id, {resolve, reject});
      this.ws.send(JSON.stringify({id, cmd, token: this.token || undefined, ...args}));
    });
  }
}
