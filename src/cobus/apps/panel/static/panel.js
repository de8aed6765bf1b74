// The operator panel's pages. One Link (WebSocket) per page; each page draws from its state.
import {Link} from "/static/link.js";

const $ = (sel, root = document) => root.querySelector(sel);
const el = (tag, attrs = {}, ...children) => {
  const node = document.createElement(tag);
  for (const [k, v] of Object.entries(attrs)) {
    if (k === "class") node.className = v; else node.setAttribute(k, v);
  }
  node.append(...children);
  return node;
};

function notice(text, kind = "error") {
  const box = $("#notice");
  box.textContent = text;
  box.className = kind;
  box.hidden = !text;
}

function ageText(seconds) {
  const s = Math.max(0, seconds);
  return s < 10 ? `${s.toFixed(2)} s` : `${s.toFixed(1)} s`;
}

// A time of the panel's clock as the wall-clock time of day here (HH:MM:SS.mmm).
function timeOfDay(link, t) {
  const wall = new Date(Date.now() - (link.now() - t) * 1000);
  const pad = (n, w = 2) => String(n).padStart(w, "0");
  return `${pad(wall.getHours())}:${pad(wall.getMinutes())}:${pad(wall.getSeconds())}` +
         `.${pad(wall.getMilliseconds(), 3)}`;
}

// ----------------------------------------------------------------------------- Network page
const NMT_LABEL = {start: "Start", stop: "Stop", preop: "Pre-op", reset: "Reset"};
const CONFIRM = {
  "stop:all": "Stop every node? Process data stops flowing.",
  "reset:all": "Reset every node? Each boots again and the master configures it anew.",
};

class NetworkPage {
  constructor(link) {
    this.link = link;
    this.rows = new Map();
    this.busLoad = [[], []];
    this.plot = null;
    this.incoming = [];     // events not drawn yet
    this.drawDue = false;
    $("#all-nodes").addEventListener("click", (e) => this.nmtButton(e));
    $("#demo-faults").addEventListener("click", (e) => this.faultButton(e));
    $("#nodes tbody").addEventListener("click", (e) => this.nmtButton(e));
    setInterval(() => this.tick(), 250);
  }

  async nmtButton(e) {
    const button = e.target.closest("button[data-nmt]");
    if (!button) return;
    const action = button.dataset.nmt;
    const node = button.dataset.node === "all" ? "all" : Number(button.dataset.node);
    const question = CONFIRM[`${action}:${button.dataset.node}`];
    if (question && !confirm(question)) return;
    button.disabled = true;
    try {
      await this.link.command("nmt", {node, action});
      notice("");
    } catch (err) {
      notice(err.text || String(err));
    } finally {
      button.disabled = !this.writable();
    }
  }

  async faultButton(e) {
    const button = e.target.closest("button[data-fault]");
    if (!button) return;
    button.disabled = true;
    try {
      const said = await this.link.command("demo.fault", {fault: button.dataset.fault});
      notice(`Fault injected: ${said}`, "info");
    } catch (err) {
      notice(err.text || String(err));
    } finally {
      button.disabled = !this.writable();
    }
  }

  faults(faults) {
    const bar = $("#demo-faults");
    bar.hidden = !faults;
    if (!faults) return;
    bar.replaceChildren(el("span", {class: "label"}, "Demo faults:"),
      ...faults.map((f) => el("button", {"data-fault": f.name, title: f.text, class: "fault"},
                              f.label)));
  }

  writable() {
    return !this.link.info.needs_token || Boolean(this.link.token);
  }

  snapshot(msg) {
    const body = $("#nodes tbody");
    body.replaceChildren();
    this.rows.clear();
    for (const info of msg.info.nodes || []) this.addRow(body, info);
    this.faults(msg.info.faults);
    for (const [key, value] of Object.entries(msg.state)) this.update(key, value);
    // the plot's x axis is wall-clock time here: the panel's clock moved by their offset
    const offset = Date.now() / 1000 - this.link.now();
    const series = msg.series.bus_load || [];
    this.busLoad = [series.map((s) => s[0] + offset), series.map((s) => s[1])];
    $("#events").replaceChildren();
    this.incoming = [];
    for (const ev of msg.events) this.event(ev);
    for (const b of document.querySelectorAll("button[data-nmt]")) b.disabled = !this.writable();
    if (!this.writable()) {
      notice("Read-only: this panel needs its token for commands (open the address it printed).",
             "info");
    }
    this.drawPlot();
  }

  addRow(body, info) {
    const id = info.id;
    const buttons = el("td", {class: "commands"});
    for (const [action, label] of Object.entries(NMT_LABEL)) {
      buttons.append(el("button", {"data-nmt": action, "data-node": String(id),
                                   title: `${label} node ${id}`}, label), " ");
    }
    const device = [info.vendor, info.product].filter(Boolean).join(" · ");
    const row = el("tr", {"data-node": String(id)},
      el("td", {class: "num"}, String(id)),
      el("td", {}, info.name + (info.mandatory ? " *" : "")),
      el("td", {class: "device muted", title: "from the EDS until the node answers 1008h",
                "data-eds": device}, device),
      el("td", {class: "leds"},
         el("span", {class: "led run off", title: "run LED"}),
         el("span", {class: "led error off", title: "error LED"})),
      el("td", {class: "nmt"}, "—"),
      el("td", {class: "state"}, "—"),
      el("td", {class: "diag"}, "—"),
      el("td", {class: "heard num"}, "—"),
      el("td", {class: "emcy num"}, "0"),
      el("td", {class: "problem"}, ""),
      buttons);
    body.append(row);
    this.rows.set(id, row);
  }

  update(key, value) {
    const [kind, id] = key.split("/");
    if (kind === "node") this.node(Number(id), value);
    else if (kind === "master") this.master(value);
  }

  node(id, v) {
    const row = this.rows.get(id);
    if (!row) return;
    const set = (cls, text) => { $(`.${cls}`, row).textContent = text; };
    set("nmt", v.nmt ? v.nmt.replace("_", "-") : "—");
    set("state", `${v.state} ${v.state_text}`);
    set("diag", `${v.diagnostic} ${v.diagnostic_text}`);
    set("emcy", String(v.emcy));
    set("problem", v.problem || "");
    row.classList.toggle("bad", v.diagnostic !== 0);
    for (const [which, pattern] of [["run", v.run_led], ["error", v.error_led]]) {
      const led = $(`.led.${which}`, row);
      led.className = `led ${which} ${pattern.replace(" ", "-")}${pattern === "off" ? "" : " lit"}`;
      led.title = `${which} LED: ${pattern}`;
    }
    const d = v.device || {};
    if (d.name || d.vendor_id !== undefined) {
      const cell = $(".device", row);
      const ids = d.vendor_id !== undefined
        ? ` (vendor 0x${d.vendor_id.toString(16).toUpperCase()}, product 0x${(d.product_code ?? 0).toString(16).toUpperCase()})`
        : "";
      cell.textContent = (d.name || cell.dataset.eds) + ids;
      cell.classList.remove("muted");
      cell.title = "1008h and 1018h as the node answered";
    }
  }

  master(m) {
    const rows = [
      ["State", `${m.state} (${m.status})`], ["Bus", m.bus_state],
      ["TX / RX errors", `${m.tx_errors ?? "—"} / ${m.rx_errors ?? "—"}`],
      ["Bus-off count", m.bus_off_count], ["Frames", m.frames], ["SYNC count", m.sync_count],
      ["Send errors", m.send_errors],
    ];
    $("#master").replaceChildren(...rows.flatMap(([k, v]) => [el("dt", {}, k), el("dd", {}, String(v))]));
  }

  tick() {
    const now = this.link.now();
    for (const [id, row] of this.rows) {
      const heard = this.link.state[`heard/${id}`];
      $(".heard", row).textContent = heard == null ? "—" : `${ageText(now - heard)} ago`;
    }
    if (this.link.state.bus_load !== undefined) {
      const wall = Date.now() / 1000;
      this.busLoad[0].push(wall);
      this.busLoad[1].push(this.link.state.bus_load);
      const cut = this.busLoad[0].findIndex((t) => t >= wall - 60);
      if (cut > 0) { this.busLoad[0].splice(0, cut); this.busLoad[1].splice(0, cut); }
      this.drawPlot();
    }
  }

  drawPlot() {
    const box = $("#bus-load");
    if (typeof uPlot === "undefined") return;
    if (this.plot === null) {
      this.plot = new uPlot({
        width: Math.max(300, box.clientWidth || 500), height: 160,
        scales: {x: {time: true}, y: {range: [0, 100]}},
        axes: [{}, {label: "%"}],
        series: [{}, {label: "bus load %", stroke: "#0b63c5", width: 1.5, points: {show: false}}],
        legend: {show: false},
      }, this.busLoad, box);
    } else {
      this.plot.setData(this.busLoad);
    }
  }

  // Events are listed newest first, the last 200; a burst of them (an EMCY storm) is drawn
  // once, after the messages that brought it.
  event(ev) {
    this.incoming.push(ev);
    if (this.incoming.length > 200) this.incoming.splice(0, this.incoming.length - 200);
    if (!this.drawDue) {
      this.drawDue = true;
      setTimeout(() => this.drawEvents(), 0);
    }
  }

  drawEvents() {
    this.drawDue = false;
    const list = $("#events");
    const items = this.incoming.reverse().map((ev) =>
      el("li", {class: ev.level || "info", "data-seq": String(ev.seq)},
        el("time", {}, timeOfDay(this.link, ev.time)), ev.text));
    this.incoming = [];
    list.prepend(...items);
    while (list.children.length > 200) list.lastChild.remove();
  }
}

// ----------------------------------------------------------------------------- Alarms page
function dateTime(epoch) {
  if (epoch == null) return "";
  const d = new Date(epoch * 1000);
  const pad = (n) => String(n).padStart(2, "0");
  return `${d.getFullYear()}-${pad(d.getMonth() + 1)}-${pad(d.getDate())} ` +
         `${pad(d.getHours())}:${pad(d.getMinutes())}:${pad(d.getSeconds())}`;
}

const nodeText = (node) => (node == null ? "—" : String(node));
// EMCY codes as the documents write them (7305h), other codes in decimal
const codeText = (source, code) =>
  source === "emcy" ? `${code.toString(16).toUpperCase().padStart(4, "0")}h` : String(code);

class AlarmsPage {
  constructor(link) {
    this.link = link;
    this.historyDue = null;
    $("#ack-all").addEventListener("click", () => this.ack({all: true}, $("#ack-all")));
    $("#active-alarms tbody").addEventListener("click", (e) => {
      const button = e.target.closest("button[data-ack]");
      if (button) this.ack(JSON.parse(button.dataset.ack), button);
    });
    const form = $("#history-filter");
    form.addEventListener("submit", (e) => { e.preventDefault(); this.history(); });
    form.addEventListener("input", () => this.csvLink());
    window.addEventListener("hashchange", () => { if (this.visible()) this.history(); });
  }

  visible() { return location.hash === "#alarms"; }

  enabled(info) { return Boolean(info.alarms); }

  snapshot(msg) {
    const on = this.enabled(msg.info);
    $('#pages a[data-page="alarms"]').hidden = !on;
    $("#current-alarm").hidden = !on;
    if (!on) return;
    $("#ack-all").disabled = !pages.network.writable();
    this.update("alarms/current", msg.state["alarms/current"]);
    this.update("alarms/active", msg.state["alarms/active"] || []);
    this.update("alarms/summary", msg.state["alarms/summary"] || {});
    this.csvLink();
    if (this.visible()) this.history();
  }

  update(key, value) {
    if (key === "alarms/current") this.current(value);
    else if (key === "alarms/active") {
      this.active(value);
      this.current(this.link.state["alarms/current"]);  // its "n of m" follows the list
    }
    else if (key === "alarms/summary") {
      const count = $("#alarm-count");
      count.textContent = String(value.unacknowledged || 0);
      count.hidden = !value.unacknowledged;
    }
  }

  current(alarm) {
    const line = $("#current-alarm");
    if (!alarm) {
      line.className = "alarm-line none";
      line.textContent = "no active alarm";
      return;
    }
    const active = this.link.state["alarms/active"] || [];
    const position = active.findIndex((a) => a.source === alarm.source &&
                                              a.node === alarm.node && a.code === alarm.code);
    const node = alarm.node == null ? "" : `node ${alarm.node} `;
    line.className = `alarm-line ${alarm.severity}`;
    line.replaceChildren(
      `${node}${alarm.source} ${alarm.code_text}: ${alarm.text} `,
      el("span", {class: "which"},
         `${position + 1} of ${active.length} · since ${dateTime(alarm.raised_at)}` +
         (alarm.acknowledged_by ? ` · acknowledged by ${alarm.acknowledged_by}` : " · not acknowledged")));
  }

  active(alarms) {
    const body = $("#active-alarms tbody");
    const writable = pages.network.writable();
    body.replaceChildren(...alarms.map((a) => {
      const key = JSON.stringify({source: a.source, node: a.node, code: a.code});
      const button = a.acknowledged_by ? "" :
        el("button", {"data-ack": key, ...(writable ? {} : {disabled: ""})}, "Acknowledge");
      return el("tr", {class: `sev-${a.severity}${a.acknowledged_by ? "" : " unacked"}`},
        el("td", {}, dateTime(a.raised_at)), el("td", {class: "num"}, nodeText(a.node)),
        el("td", {}, a.source), el("td", {}, a.code_text), el("td", {}, a.text),
        el("td", {class: "sev"}, a.severity), el("td", {}, a.acknowledged_by || ""),
        el("td", {}, button));
    }));
    $("#no-active").hidden = alarms.length > 0;
  }

  async ack(args, button) {
    button.disabled = true;
    try {
      await this.link.command("alarm.ack", args);
      notice("");
    } catch (err) {
      notice(err.text || String(err));
    } finally {
      button.disabled = !pages.network.writable();  // (a row's button goes with its row)
    }
  }

  filters() {
    const form = new FormData($("#history-filter"));
    const out = {};
    const node = form.get("node");
    if (node !== "") out.node = Number(node);
    const source = String(form.get("source") || "").trim();
    if (source) out.source = source;
    const active = form.get("active");
    if (active) out.active = active === "true";
    const since = form.get("since");
    if (since) out.since = new Date(since).getTime() / 1000;
    return out;
  }

  csvLink() {
    const query = new URLSearchParams();
    for (const [k, v] of Object.entries(this.filters())) query.set(k, String(v));
    if (this.link.token) query.set("token", this.link.token);  // (reading may need it)
    const text = query.toString();
    $("#history-csv").href = `/alarms.csv${text ? `?${text}` : ""}`;
  }

  async history() {
    if (!this.enabled(this.link.info)) return;
    const note = $("#history-note");
    try {
      const rows = await this.link.command("alarm.history", {...this.filters(), limit: 500});
      note.hidden = rows.length > 0;
      note.textContent = "No alarm in the history matches.";
      $("#alarm-history tbody").replaceChildren(...rows.map((r) => el("tr",
        {class: `sev-${r.severity}`, "data-id": String(r.id)},
        el("td", {}, dateTime(r.raised_at)), el("td", {class: "num"}, nodeText(r.node)),
        el("td", {}, r.source), el("td", {}, codeText(r.source, r.code)), el("td", {}, r.text),
        el("td", {class: "sev"}, r.severity),
        el("td", {}, r.cleared_at == null ? "active" : dateTime(r.cleared_at)),
        el("td", {}, r.acknowledged_by ? `${dateTime(r.acknowledged_at)} by ${r.acknowledged_by}` : ""))));
    } catch (err) {
      note.hidden = false;
      note.textContent = err.text || String(err);
    }
  }

  event(ev) {
    if (ev.kind !== "alarm" || !this.visible()) return;
    clearTimeout(this.historyDue);  // several changes at once: one read of the history
    this.historyDue = setTimeout(() => this.history(), 200);
  }
}

// ----------------------------------------------------------------------------- Drive pages
const PLOTTED = [["speed", "speed"], ["position", "position"], ["current", "current"],
                 ["temperature", "temperature °C"]];

class DrivePage {
  constructor(link) {
    this.link = link;
    this.name = null;
    this.series = {};   // "drive/<name>/<key>" -> [[t...], [v...]]
    this.plots = {};
    this.confirmed = new Set();  // drives whose first enable the operator confirmed
    $("#page-drive").addEventListener("click", (e) => {
      const button = e.target.closest("button[data-action]");
      if (button) this.action(button.dataset.action, button);
    });
    $("#drive-setpoint").addEventListener("submit", (e) => { e.preventDefault(); this.setpoint(); });
    $("#drive-position").addEventListener("submit", (e) => { e.preventDefault(); this.position(); });
    setInterval(() => this.tick(), 250);
    // the panel reads a drive's actual values only while a page shows it: say so
    setInterval(() => this.watch(), 2000);
  }

  watch() {
    const name = this.current();
    if (name === null || !this.drives().some((d) => d.name === name)) return;
    this.link.command("drive.watch", {drive: name}).catch(() => {});
  }

  current() {
    const m = /^#drive-(.+)$/.exec(location.hash);
    return m ? decodeURIComponent(m[1]) : null;
  }

  drives() { return this.link.info.drives || []; }

  snapshot(msg) {
    $("#drive-links").replaceChildren(...this.drives().map((d) =>
      el("a", {href: `#drive-${encodeURIComponent(d.name)}`, "data-page": `drive-${d.name}`},
         `Drive: ${d.name}`)));
    const offset = Date.now() / 1000 - this.link.now();
    for (const [key, samples] of Object.entries(msg.series)) {
      if (key.startsWith("drive/")) {
        this.series[key] = [samples.map((x) => x[0] + offset), samples.map((x) => x[1])];
      }
    }
    this.show();
  }

  show() {
    const name = this.current();
    if (name === this.name && this.name !== null) return this.render();
    this.name = name;
    $("#drive-plots").replaceChildren();
    this.plots = {};
    if (name !== null) {
      this.watch();
      this.render();
    }
  }

  info() { return this.drives().find((d) => d.name === this.name); }

  render() {
    const info = this.info();
    const d = this.link.state[`drive/${this.name}`];
    if (!info || !d) return;
    const writable = pages.network.writable();
    $("#drive-title").textContent = `${info.name} (node ${info.node}, ${info.kind === "zapi" ? "ZAPI" : "CiA 402"})`;
    const state = $("#drive-state");
    state.textContent = d.kind === "zapi" ? d.state : d.state_text;
    if (d.read_error) state.textContent += ` (not read: ${d.read_error})`;
    $("#drive-note").hidden = !d.note;
    $("#drive-note").textContent = d.note || "";
    state.className = `drive-state${d.fault ? " fault" : d.enabled ? " enabled" : ""}`;
    const panelHolds = d.holder === "panel";
    $("#drive-holder").textContent = panelHolds ? "commanded from this panel" : "commanded by the application";
    $("#drive-take").hidden = panelHolds;
    $("#drive-give").hidden = !panelHolds;
    // a ZAPI inverter the panel starts itself: no handshake, nothing but starting it
    const idle = info.kind === "zapi" && !d.handshake;
    for (const b of document.querySelectorAll("#drive-buttons button")) {
      const action = b.dataset.action;
      b.hidden = Boolean(b.dataset.kind) && b.dataset.kind !== info.kind;
      if (action === "handshake") b.hidden = b.hidden || !info.on_demand || d.handshake;
      if (action === "end_handshake") b.hidden = b.hidden || !info.on_demand || !d.handshake;
      const stop = ["disable", "halt", "stop", "release", "end_handshake"].includes(action);
      b.disabled = !writable || (!panelHolds && !stop) || (idle && action !== "handshake");
    }
    $("#quick-stop").hidden = info.kind !== "cia402";
    for (const b of ["#quick-stop", "#drive-take", "#drive-give"]) $(b).disabled = !writable;
    // a set-point goes only to an enabled drive in its mode (the panel never sets the mode)
    const canCommand = writable && panelHolds && d.enabled;
    $("#drive-setpoint button").disabled = !canCommand || (info.kind === "cia402" && d.mode !== 3);
    $("#drive-position").hidden = info.kind !== "cia402";
    $("#drive-position button").disabled = !canCommand || d.mode !== 1;
    $("#drive-unit").textContent = info.unit;
    $("#drive-limits").textContent = d.max_velocity ? `at most ${d.max_velocity} ${info.unit}` :
      info.kind === "zapi" ? "at most 327.67 Hz" : "";
    if (info.kind === "cia402") {
      const unit = info.unit.replace(/\/s$/, "");
      $(".drive-position-unit").textContent = unit;
      $("#drive-position-limits").textContent = d.position_limits
        ? `within ${d.position_limits[0]}..${d.position_limits[1]} ${unit}` : "";
    }
    const rows = [];
    for (const [key, label] of PLOTTED) {
      const v = d.actual[key];
      if (v !== undefined) rows.push([label, v === null ? "—" : Number(v).toFixed(key === "temperature" ? 1 : 0)]);
    }
    if (d.setpoint !== undefined) rows.push(["set-point", `${d.setpoint} Hz`]);
    if (d.mode_text) rows.push(["mode", d.mode_text]);
    if (d.controlword !== undefined) rows.push(["controlword", `0x${d.controlword.toString(16).toUpperCase().padStart(4, "0")}`]);
    $("#drive-values").replaceChildren(...rows.flatMap(([k, v]) => [el("dt", {}, k), el("dd", {}, String(v))]));
    if (d.statusword !== undefined) {
      $("#drive-statusword").textContent = `0x${d.statusword.toString(16).toUpperCase().padStart(4, "0")} ${d.state}`;
      $("#drive-flags").replaceChildren(...d.flags.map((f) => el("li", {}, f)));
    } else {
      $("#drive-statusword").textContent = d.kind === "zapi" ? `handshake cycles ${d.cycles}` : "—";
      $("#drive-flags").replaceChildren();
    }
    const alarms = (this.link.state["alarms/active"] || []).filter((a) => a.node === info.node);
    const texts = alarms.map((a) => `${a.source} ${a.code_text}: ${a.text}`);
    if (d.alarm) texts.unshift(`alarm ${d.alarm}: ${d.alarm_text}`);
    $("#drive-alarm").textContent = texts.length ? [...new Set(texts)].join("; ") : "none";
    $("#drive-alarm").className = texts.length ? "problem" : "muted";
  }

  async action(action, button) {
    const info = this.info();
    if (!info) return;
    const args = {drive: info.name, action};
    if (action === "enable") {
      if (!this.confirmed.has(info.name)) {
        const text = info.kind === "zapi"
          ? `Enable ${info.name}? Its main contactor closes; it stands at 0 Hz until you set a speed.`
          : `Enable ${info.name}? Its power stage switches on with the set-point 0; it moves once you set a speed.`;
        if (!confirm(text)) return;
        this.confirmed.add(info.name);
      }
      args.confirm = true;
    }
    if (action === "end_handshake" &&
        !confirm(`End ${info.name}'s handshake? It is released first; the inverter then raises its CAN BUS KO alarm.`)) {
      return;
    }
    if (action === "give" &&
        !confirm(`Give ${info.name} back to the application? It commands the drive again and may start it.`)) {
      return;
    }
    button.disabled = true;
    try {
      await this.link.command("drive", args);
      notice("");
    } catch (err) {
      notice(err.text || String(err));
    } finally {
      button.disabled = !pages.network.writable();
      this.render();
    }
  }

  async setpoint() {
    const info = this.info();
    if (!info) return;
    const form = new FormData($("#drive-setpoint"));
    const text = String(form.get("speed") || "").trim();
    const magnitude = Number(text);
    if (text === "" || !Number.isFinite(magnitude)) {
      notice("Give the speed as a number.");
      return;
    }
    const value = Number(form.get("direction")) * magnitude;
    try {
      await this.link.command("drive", {drive: info.name, action: "speed", value});
      notice("");
    } catch (err) {
      notice(err.text || String(err));
    }
  }

  async position() {
    const info = this.info();
    if (!info) return;
    const form = new FormData($("#drive-position"));
    const text = String(form.get("position") || "").trim();
    const value = Number(text);
    if (text === "" || !Number.isFinite(value)) {  // (never 0 for a field left unreadable)
      notice("Give the position as a number.");
      return;
    }
    const relative = form.get("relative") === "on";
    try {
      await this.link.command("drive", {drive: info.name, action: "position", value, relative});
      notice("");
    } catch (err) {
      notice(err.text || String(err));
    }
  }

  tick() {
    const wall = Date.now() / 1000;
    for (const d of this.drives()) {
      const state = this.link.state[`drive/${d.name}`];
      if (!state) continue;
      for (const [key] of PLOTTED) {
        const v = state.actual[key];
        if (v === undefined || v === null) continue;
        const id = `drive/${d.name}/${key}`;
        const s = this.series[id] || (this.series[id] = [[], []]);
        s[0].push(wall); s[1].push(v);
        const cut = s[0].findIndex((t) => t >= wall - 60);
        if (cut > 0) { s[0].splice(0, cut); s[1].splice(0, cut); }
      }
    }
    if (this.name !== null && location.hash.startsWith("#drive-")) this.draw();
  }

  draw() {
    if (typeof uPlot === "undefined") return;
    const info = this.info();
    if (!info) return;
    for (const [key, label] of PLOTTED) {
      const id = `drive/${info.name}/${key}`;
      const data = this.series[id];
      if (!data || data[0].length === 0) continue;
      if (!this.plots[key]) {
        const box = el("div", {class: "plot", "data-plot": key},
                       el("h3", {}, key === "speed" ? `speed (${info.unit})` : label));
        $("#drive-plots").append(box);
        this.plots[key] = new uPlot({
          width: Math.max(300, $("#drive-plots").clientWidth || 500), height: 130,
          scales: {x: {time: true}},
          series: [{}, {label, stroke: "#0b63c5", width: 1.5, points: {show: false}}],
          legend: {show: false},
        }, data, box);
      } else {
        this.plots[key].setData(data);
      }
    }
  }

  update(key) {
    if (this.name !== null && (key === `drive/${this.name}` || key === "alarms/active")) this.render();
  }

  event() {}
}

// ----------------------------------------------------------------------------- Parameters
const hex = (n, w) => n.toString(16).toUpperCase().padStart(w, "0");
const address = (o) => `${hex(o.index, 4)}h:${hex(o.subindex, 2)}`;

class ParametersPage {
  constructor(link) {
    this.link = link;
    this.loaded = null;
    $("#param-search").addEventListener("submit", (e) => { e.preventDefault(); this.search(); });
    $("#param-search select").addEventListener("change", () => { this.status(); this.search(); });
    $("#param-diff").addEventListener("click", () => this.diff("network"));
    $("#param-diff-set").addEventListener("click", () => this.diff("parameters"));
    $("#param-save").addEventListener("click", () => this.save());
    $("#param-list tbody").addEventListener("click", (e) => {
      const button = e.target.closest("button[data-do]");
      if (button) this[button.dataset.do](button.closest("tr"), button);
    });
    window.addEventListener("hashchange", () => this.shown());
  }

  node() { return Number(new FormData($("#param-search")).get("node")); }

  snapshot(msg) {
    const info = msg.info.parameters;
    $('#pages a[data-page="parameters"]').hidden = !info;
    if (!info) return;
    const select = $("#param-search select");
    const was = select.value;
    select.replaceChildren(...info.nodes.map((n) =>
      el("option", {value: String(n.id)}, `${n.id} ${n.name} (${n.eds})`)));
    if (was) select.value = was;
    const writable = pages.network.writable();
    $("#param-save").disabled = !writable;
    this.status();
    this.shown();
  }

  // The parameter manager's word on the node shown (when it parameterises it at boot).
  status() {
    const node = this.node();
    const info = (this.link.info.parameters?.nodes || []).find((n) => n.id === node);
    $("#param-diff-set").hidden = !(info && info.set);
    const line = $("#param-status");
    const status = (this.link.state["parameters/status"] || []).find((s) => s.node === node);
    line.hidden = !status;
    if (!status) return;
    line.textContent = `Parameter file ${status.set}: ${status.summary}`;
    line.className = status.ok === false ? "problem" : "muted";
  }

  shown() {
    if (location.hash === "#parameters" && this.loaded === null) this.search();
  }

  async search() {
    const form = new FormData($("#param-search"));
    const node = this.node();
    const asked = (this.asked = (this.asked || 0) + 1);
    try {
      const found = await this.link.command("param.list", {node, query: String(form.get("query") || "")});
      if (asked !== this.asked) return;  // a newer search was sent meanwhile: its list counts
      this.loaded = node;
      const writable = pages.network.writable();
      $("#param-list tbody").replaceChildren(...found.objects.map((o) => this.row(o, writable)));
      $("#param-note").textContent = found.more ? `${found.more} more objects match: search for fewer.`
        : `${found.objects.length} object(s).`;
    } catch (err) {
      $("#param-note").textContent = err.text || String(err);
    }
  }

  row(o, writable) {
    const limits = o.low == null && o.high == null ? "" : `${o.low ?? ""} .. ${o.high ?? ""}`;
    const name = el("td", {}, o.name);
    if (o.command) name.append(el("span", {class: "badge", title: o.command}, "command"));
    const value = el("td", {class: "value"});
    const buttons = el("td", {});
    if (o.access !== "wo") buttons.append(el("button", {"data-do": "read"}, "Read"), " ");
    if (["rw", "wo", "rww", "rwr"].includes(o.access)) {
      value.append(el("input", {name: "value", "aria-label": `value of ${o.name}`,
                                placeholder: o.type}));
      buttons.append(el("button", {"data-do": "write", ...(writable ? {} : {disabled: ""})}, "Write"));
    }
    const row = el("tr", {"data-index": String(o.index), "data-subindex": String(o.subindex)},
      el("td", {class: "mono"}, address(o)), name, el("td", {}, o.type), el("td", {}, o.access),
      el("td", {}, limits), el("td", {}, o.default == null ? "" : String(o.default)), value, buttons);
    row.info = o;
    return row;
  }

  async read(row) {
    const o = row.info;
    try {
      const got = await this.link.command("param.read", {node: this.loaded, index: o.index, subindex: o.subindex});
      // (the list may have been drawn again meanwhile: the value goes to the row shown now)
      row = $(`#param-list tr[data-index="${o.index}"][data-subindex="${o.subindex}"]`) || row;
      const input = $("input", row);
      if (input) input.value = String(got.value);
      else $("td.value", row).textContent = String(got.value);
      row.title = `raw ${got.raw}`;
      notice("");
    } catch (err) {
      notice(err.text || String(err));
    }
  }

  async write(row, button) {
    const o = row.info;
    const text = $("input", row).value.trim();
    const args = {node: this.loaded, index: o.index, subindex: o.subindex,
                  value: text === "" ? null : text};
    if (o.command) {
      if (!confirm(`Writing ${o.name} is a command (${o.command}): it can switch the device on or move it. Write ${text}?`)) return;
      args.command = true;
    }
    button.disabled = true;
    try {
      const done = await this.link.command("param.write", args);
      notice(`${done.name} = ${done.value} written`, "info");
    } catch (err) {
      notice(err.text || String(err));
    } finally {
      button.disabled = false;
    }
  }

  async save() {
    const node = this.node();
    if (!confirm(`Save node ${node}'s parameters (1010h sub 1)? They survive its next power cycle.`)) return;
    try {
      await this.link.command("param.save", {node});
      notice(`node ${node}: parameters saved`, "info");
    } catch (err) {
      notice(err.text || String(err));
    }
  }

  async diff(against) {
    const node = this.node();
    const box = $("#param-diff-box");
    try {
      const got = await this.link.command("param.diff", {node, against});
      const file = against === "network" ? "the network file" : `the parameter file ${got.file}`;
      $("#param-diff-title").textContent = `Against ${file}`;
      box.hidden = false;
      $("#param-diff-table tbody").replaceChildren(...got.rows.map((r) =>
        el("tr", {class: r.same === false ? "differs" : ""},
          el("td", {class: "mono"}, address(r)), el("td", {}, r.name), el("td", {}, String(r.file)),
          el("td", {}, r.node == null ? "—" : String(r.node)),
          el("td", {}, r.same === true ? "same" : r.same === false ? "differs" : r.note))));
      $("#param-note").textContent = got.rows.length
        ? `${got.differ} of ${got.rows.length} object(s) of ${file} differ on node ${node}.`
        : `${file[0].toUpperCase()}${file.slice(1)} sets nothing on node ${node}.`;
    } catch (err) {
      notice(err.text || String(err));
    }
  }

  update(key) {
    if (key === "parameters/status") this.status();
  }

  event() {}
}

// ----------------------------------------------------------------------------- Trace
const KINDS = ["nmt", "hb", "sync", "time", "emcy", "sdo", "pdo", "lss", "other"];
const KEEP = 1000;  // records the page keeps (newest first)

class TracePage {
  constructor(link) {
    this.link = link;
    this.records = [];      // newest first
    this.waiting = [];      // while paused
    this.paused = false;
    this.last = 0;          // the number of the last record taken
    this.missed = 0;        // records the page never got (it fell behind a batch)
    $("#trace-kinds").replaceChildren(...KINDS.map((k) =>
      el("label", {}, el("input", {type: "checkbox", name: "kind", value: k, checked: ""}), ` ${k}`)));
    $("#trace-pause").addEventListener("click", () => this.pause());
    $("#trace-clear").addEventListener("click", () => { this.records = []; this.draw(); });
    $("#trace-filter").addEventListener("input", () => this.draw());
    $("#trace-filter").addEventListener("submit", (e) => e.preventDefault());
    // the panel decodes only while a page shows the trace: say so every two seconds
    setInterval(() => this.watch(), 2000);
  }

  watch() {
    if (location.hash !== "#trace" || !this.link.info.trace) return;
    this.link.command("trace.watch").catch(() => {});
  }

  snapshot(msg) {
    $('#pages a[data-page="trace"]').hidden = !msg.info.trace;
    const batch = msg.state["trace/batch"];
    if (batch) this.take(batch);
  }

  update(key, value) {
    if (key === "trace/batch") this.take(value);
  }

  take(batch) {
    if (batch.records.length && batch.records[batch.records.length - 1].n < this.last) {
      this.last = 0;  // the panel started again: its numbers too
      this.missed = 0;
    }
    const fresh = batch.records.filter((r) => r.n > this.last);
    if (!fresh.length) return;
    if (this.last && fresh[0].n > this.last + 1) this.missed += fresh[0].n - this.last - 1;
    this.last = fresh[fresh.length - 1].n;
    if (this.paused) {
      this.waiting.push(...fresh);
      if (this.waiting.length > KEEP) this.waiting.splice(0, this.waiting.length - KEEP);
    } else {
      this.records.unshift(...fresh.reverse());
      if (this.records.length > KEEP) this.records.length = KEEP;
      if (location.hash === "#trace") this.draw();
    }
    this.note();
  }

  pause() {
    this.paused = !this.paused;
    $("#trace-pause").textContent = this.paused ? "Resume" : "Pause";
    if (!this.paused) {
      this.records.unshift(...this.waiting.reverse());
      this.waiting = [];
      if (this.records.length > KEEP) this.records.length = KEEP;
      this.draw();
    }
    this.note();
  }

  filter() {
    const form = new FormData($("#trace-filter"));
    const node = form.get("node");
    const kinds = new Set(form.getAll("kind"));
    const text = String(form.get("text") || "").toLowerCase();
    return (r) => kinds.has(r.kind) && (node === "" || r.node === Number(node)) &&
                  (!text || r.text.toLowerCase().includes(text));
  }

  draw() {
    const keep = this.filter();
    const shown = this.records.filter(keep).slice(0, 500);
    $("#trace-records tbody").replaceChildren(...shown.map((r) => el("tr", {class: r.kind},
      el("td", {}, timeOfDay(this.link, r.time)), el("td", {}, r.kind),
      el("td", {}, r.node == null ? "" : String(r.node)),
      el("td", {}, hex(r.cob_id, 3)), el("td", {}, r.text))));
    this.note(shown.length);
  }

  note(shown) {
    const parts = [`${this.last} records decoded`];
    if (shown !== undefined) parts.push(`${shown} shown`);
    if (this.paused) parts.push(`paused: ${this.waiting.length} waiting`);
    if (this.missed) parts.push(`${this.missed} not shown (the bus was faster than the page)`);
    $("#trace-note").textContent = parts.join(" · ");
  }

  event() {}
}

// ----------------------------------------------------------------------------- the pages
const pages = {};
const link = new Link({
  snapshot(msg) {
    $("#title").textContent = msg.info.title || "cobus";
    document.title = `${msg.info.title || "cobus"} panel`;
    for (const page of Object.values(pages)) page.snapshot(msg);
    show();
  },
  delta(values) {
    for (const page of Object.values(pages)) {
      for (const [key, value] of Object.entries(values)) page.update(key, value);
    }
  },
  event(ev) { for (const page of Object.values(pages)) page.event(ev); },
  error(msg) { notice(msg.text); },
  status(up, text) {
    const box = $("#link");
    box.textContent = text;
    box.className = `link ${up ? "up" : "down"}`;
  },
});
pages.network = new NetworkPage(link);
pages.alarms = new AlarmsPage(link);
pages.drive = new DrivePage(link);
pages.parameters = new ParametersPage(link);
pages.trace = new TracePage(link);

function show() {
  const name = (location.hash || "#network").slice(1);
  const page = name.startsWith("drive-") ? "drive" : name;
  for (const section of document.querySelectorAll(".page")) {
    section.hidden = section.id !== `page-${page}`;
  }
  for (const a of document.querySelectorAll("#pages a")) {
    a.classList.toggle("current", a.dataset.page === name);
  }
  if (page === "drive") pages.drive.show();
  if (page === "trace") {
    pages.trace.watch();
    pages.trace.draw();
  }
}
window.addEventListener("hashchange", show);
show();
window.cobusPanel = {link, pages};
