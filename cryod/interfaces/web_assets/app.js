// cryod's live page: the status as `cryod ctl status` gives it, pushed by the daemon (server-sent
// events), and the last hour in one-second bins drawn on canvases. Nothing is loaded from elsewhere.
"use strict";

const HOUR_S = 3600;
const view = { spanS: 600, endS: null };       // the charts' window; endS null: follow the newest bin
let bins = [];
let latest = {};
let drawPending = false;

// -- numbers ---------------------------------------------------------------------------------------
const FORMATS = {
  kelvin6: (v) => `${v.toFixed(6)} K`,
  kelvin4: (v) => `${v.toFixed(4)} K`,
  microkelvin: (v) => `${(v * 1e6 >= 0 ? "+" : "")}${(v * 1e6).toFixed(1)} µK`,
  microkelvin_unsigned: (v) => `${(v * 1e6).toFixed(1)} µK`,
  milliwatt: (v) => `${(v * 1e3).toFixed(3)} mW`,
  rate: (v) => (v === 0 ? "steps" : `${v} K/min`),
  seconds: (v) => `${v.toFixed(2)} s`,
  milliseconds: (v) => `${v.toFixed(2)} ms`,
  count: (v) => `${v}`,
  text: (v) => `${v}`,
};

function show(id, value) {
  const element = document.getElementById(id);
  if (!element) return;
  const missing = value === null || value === undefined || (typeof value === "number" && !isFinite(value));
  element.dataset.value = missing ? "" : String(value);
  element.textContent = missing ? "–" : FORMATS[element.dataset.format || "text"](value);
}

function piPart(status) {
  if (status.pi_proportional_W === undefined) return null;
  return (status.pi_proportional_W ?? 0) + (status.pi_integral_W ?? 0);
}

function renderStatus(status) {
  latest = status;
  const state = document.getElementById("state");
  state.textContent = status.state ?? "–";
  state.dataset.value = status.state ?? "";
  state.className = "state " + String(status.state ?? "").split(":")[0];
  const error = status.T2_K != null && status.setpoint_K != null ? status.T2_K - status.setpoint_K : null;
  for (const key of ["T2_K", "T2_average_K", "setpoint_K", "target_K", "ramp_K_per_min", "T5_K", "heater_W",
                     "ff_W", "line_amplitude_K", "ff_limit_K", "time_s", "overruns", "lateness_ms_p99"]) {
    show(key, status[key]);
  }
  show("error_K", error);
  show("pi_W", piPart(status));
  show("last_fault", status.last_fault ?? "none");
  const newest = bins.length ? bins[bins.length - 1] : null;
  show("ff_band", newest && newest.ff_min_W !== null
    ? `${(newest.ff_min_W * 1e3).toFixed(1)} to ${(newest.ff_max_W * 1e3).toFixed(1)} mW` : null);
  const meter = document.getElementById("line_meter");
  if (status.line_amplitude_K != null && status.ff_limit_K) {
    meter.value = status.line_amplitude_K / status.ff_limit_K;
  }
  const faults = document.getElementById("faults");
  const faulted = String(status.state ?? "").startsWith("fault") || status.state === "stopped";
  faults.hidden = !(faulted || status.last_fault);
  faults.textContent = status.last_fault ? `last fault: ${status.last_fault}` : (faulted ? status.state : "");
  const alarms = document.getElementById("alarms");
  const raised = Array.isArray(status.alarms) ? status.alarms : [];
  alarms.hidden = raised.length === 0;
  alarms.replaceChildren(...raised.map((alarm) => {
    const item = listItem(alarmText(alarm));
    if (alarm.name) item.dataset.alarm = alarm.name;
    return item;
  }));
  if (status.record_path !== undefined) show("record_path", status.record_path);
}

// An alarm of the status (cryod ctl status): its name, raised or latched, acknowledged or not, and its figure
// when it was raised.
function alarmText(alarm) {
  if (typeof alarm === "string") return alarm;
  const acknowledged = alarm.acknowledged ? ", acknowledged" : "";
  return `${alarm.name} ${alarm.state}${acknowledged}: ${alarm.raised_message || alarm.message}`;
}

function listItem(text) {
  const item = document.createElement("li");
  item.textContent = text;
  return item;
}

function addEvents(events) {
  const notes = document.getElementById("notes");
  const list = document.getElementById("events");
  for (const event of events) {
    const when = event.time_s === null ? "" : `${event.time_s.toFixed(1)} s: `;
    const target = event.kind === "note" ? notes : list;
    target.prepend(listItem(`${when}${event.kind === "note" ? "" : event.kind + ": "}${event.message}`));
    while (target.children.length > 50) target.lastChild.remove();
  }
}

// -- charts --------------------------------------------------------------------------------------
const CHARTS = {
  "chart-T2": { bands: [["T2_min_K", "T2_max_K", "#1f77b4"]], lines: [["setpoint_K", "#d62728"]], scale: 1 },
  "chart-error": { bands: [["error_min", "error_max", "#2ca02c"]], lines: [], scale: 1e6, derived: true },
  "chart-T5": { bands: [["T5_min_K", "T5_max_K", "#9467bd"]], lines: [["T5_mean_K", "#5b3a8c"]], scale: 1 },
  "chart-heater": { bands: [["heater_min_W", "heater_max_W", "#ff7f0e"], ["ff_min_W", "ff_max_W", "#17becf"]],
                    lines: [["pi_W", "#8c564b"]], scale: 1e3 },
  "chart-line": { bands: [], lines: [["line_amplitude_K", "#1f77b4"], ["line_limit_K", "#d62728"]], scale: 1e6 },
};

function value(bin, key) {
  if (key === "error_min") return bin.setpoint_K === null || bin.T2_min_K === null ? null : bin.T2_min_K - bin.setpoint_K;
  if (key === "error_max") return bin.setpoint_K === null || bin.T2_max_K === null ? null : bin.T2_max_K - bin.setpoint_K;
  return bin[key];
}

function windowBins() {
  if (!bins.length) return { shown: [], start: 0, end: 0 };
  const end = view.endS === null ? bins[bins.length - 1].time_s + 1 : view.endS;
  const start = end - view.spanS;
  return { shown: bins.filter((bin) => bin.time_s >= start && bin.time_s < end), start, end };
}

function draw() {
  drawPending = false;
  const { shown, start, end } = windowBins();
  show("window", bins.length ? `${((end - start) / 60).toFixed(1)} min up to ${end.toFixed(0)} s` : null);
  for (const [id, chart] of Object.entries(CHARTS)) drawChart(document.getElementById(id), chart, shown, start, end);
}

function requestDraw() {
  if (!drawPending) {
    drawPending = true;
    requestAnimationFrame(draw);
  }
}

function drawChart(canvas, chart, shown, start, end) {
  const ratio = window.devicePixelRatio || 1;
  const width = canvas.clientWidth, height = canvas.clientHeight;
  if (canvas.width !== Math.round(width * ratio)) canvas.width = Math.round(width * ratio);
  if (canvas.height !== Math.round(height * ratio)) canvas.height = Math.round(height * ratio);
  const context = canvas.getContext("2d");
  context.setTransform(ratio, 0, 0, ratio, 0, 0);
  context.clearRect(0, 0, width, height);
  const left = 78, right = 10, top = 18, bottom = 18;
  context.font = "11px sans-serif";
  context.fillStyle = "#333";
  context.fillText(canvas.dataset.title, left, 12);
  const keys = [...chart.bands.flatMap(([low, high]) => [low, high]), ...chart.lines.map(([key]) => key)];
  let low = Infinity, high = -Infinity;
  for (const bin of shown) {
    for (const key of keys) {
      const v = value(bin, key);
      if (v !== null && v !== undefined && isFinite(v)) { low = Math.min(low, v * chart.scale); high = Math.max(high, v * chart.scale); }
    }
  }
  if (!isFinite(low)) { context.fillText("no data in this window yet", left, height / 2); return; }
  if (high - low < 1e-12) { high += 0.5; low -= 0.5; }
  const margin = (high - low) * 0.05;
  low -= margin; high += margin;
  const x = (t) => left + (t - start) / (end - start) * (width - left - right);
  const y = (v) => top + (high - v * chart.scale) / (high - low) * (height - top - bottom);
  context.strokeStyle = "#ccc";
  context.strokeRect(left, top, width - left - right, height - top - bottom);
  context.fillStyle = "#333";
  context.fillText(high.toPrecision(7), 2, top + 8);
  context.fillText(low.toPrecision(7), 2, height - bottom);
  context.fillText(`${((end - start) / 60).toFixed(1)} min`, left, height - 4);
  context.fillText("now", width - right - 24, height - 4);
  for (const [lowKey, highKey, color] of chart.bands) {
    context.fillStyle = color;
    context.globalAlpha = 0.35;
    for (const bin of shown) {
      const a = value(bin, lowKey), b = value(bin, highKey);
      if (a === null || b === null || a === undefined) continue;
      const top_ = y(b), bottom_ = y(a);
      context.fillRect(x(bin.time_s), top_, Math.max(1, x(bin.time_s + 1) - x(bin.time_s)), Math.max(1, bottom_ - top_));
    }
    context.globalAlpha = 1;
  }
  for (const [key, color] of chart.lines) {
    context.strokeStyle = color;
    context.beginPath();
    let previous = null;                       // a gap in the bins (the daemon was not running) breaks the line
    for (const bin of shown) {
      const v = value(bin, key);
      if (v === null || v === undefined) { previous = null; continue; }
      const px = x(bin.time_s + 0.5), py = y(v);
      if (previous !== null && bin.time_s - previous <= 1.5) context.lineTo(px, py); else context.moveTo(px, py);
      previous = bin.time_s;
    }
    context.stroke();
  }
}

function zoomable(canvas) {
  canvas.addEventListener("wheel", (event) => {
    event.preventDefault();
    const { start, end } = windowBins();
    const at = start + (event.offsetX - 78) / Math.max(1, canvas.clientWidth - 88) * (end - start);
    const factor = event.deltaY > 0 ? 1.25 : 0.8;
    const span = Math.min(HOUR_S, Math.max(10, view.spanS * factor));
    view.endS = at + (end - at) * span / view.spanS;
    view.spanS = span;
    document.getElementById("follow").checked = false;
    requestDraw();
  }, { passive: false });
  let dragging = null;
  canvas.addEventListener("mousedown", (event) => { dragging = { x: event.clientX, end: windowBins().end }; });
  window.addEventListener("mouseup", () => { dragging = null; });
  canvas.addEventListener("mousemove", (event) => {
    if (!dragging) return;
    const seconds = (event.clientX - dragging.x) / Math.max(1, canvas.clientWidth - 88) * view.spanS;
    view.endS = dragging.end - seconds;
    document.getElementById("follow").checked = false;
    requestDraw();
  });
  canvas.addEventListener("dblclick", () => { view.spanS = HOUR_S; view.endS = null; document.getElementById("follow").checked = true; requestDraw(); });
}

// -- control (only when the daemon allows it) --------------------------------------------------------
async function sendCommand(line) {
  const reply = document.getElementById("command_reply");
  try {
    const response = await fetch("/api/command", {
      method: "POST",
      headers: { "Content-Type": "application/json", "X-Cryod-Token": document.getElementById("token").value },
      body: JSON.stringify({ command: line }),
    });
    const answer = await response.json();
    show("command_reply", `${line}: ${answer.ok ? "" : "refused: "}${answer.message}`);
    if (answer.status) renderStatus(answer.status);
  } catch (error) {
    show("command_reply", `${line}: not sent (${error})`);
  }
  reply.className = "";
}

function setUpControl(commands) {
  if (!commands.length) return;
  document.getElementById("control").hidden = false;
  document.getElementById("setpoint-form").addEventListener("submit", (event) => {
    event.preventDefault();
    sendCommand(`setpoint ${document.getElementById("setpoint-input").value.trim()}`);
  });
  document.getElementById("ramp-form").addEventListener("submit", (event) => {
    event.preventDefault();
    sendCommand(`ramp ${document.getElementById("ramp-input").value.trim()}`);
  });
  document.getElementById("heater-off").addEventListener("click", () => sendCommand("heater-off"));
  document.getElementById("feedforward-on").addEventListener("click", () => sendCommand("feedforward on"));
  document.getElementById("feedforward-off").addEventListener("click", () => sendCommand("feedforward off"));
}

// -- start -------------------------------------------------------------------------------------------
async function start() {
  for (const button of document.querySelectorAll("button[data-span]")) {
    button.addEventListener("click", () => {
      view.spanS = Number(button.dataset.span);
      view.endS = null;
      document.getElementById("follow").checked = true;
      requestDraw();
    });
  }
  document.getElementById("follow").addEventListener("change", (event) => {
    view.endS = event.target.checked ? null : windowBins().end;
    requestDraw();
  });
  for (const id of Object.keys(CHARTS)) zoomable(document.getElementById(id));
  window.addEventListener("resize", requestDraw);
  const [status, history] = await Promise.all([fetch("/api/status").then((r) => r.json()),
                                               fetch("/api/history").then((r) => r.json())]);
  bins = history.bins;
  addEvents(history.events);
  renderStatus(status.status);
  setUpControl(status.page_commands);
  requestDraw();
  // the stream starts after the last event the history gave: one folded in between is not lost
  const lastSeq = history.events.length ? history.events[history.events.length - 1].seq : 0;
  const events = new EventSource(`/api/events?after=${lastSeq}`);
  const connection = document.getElementById("connection");
  events.onopen = () => { connection.textContent = "live"; connection.className = "connection live"; };
  events.onerror = () => { connection.textContent = "connection lost, retrying"; connection.className = "connection lost"; };
  events.onmessage = (message) => {
    const frame = JSON.parse(message.data);
    if (frame.bins.length) {
      bins.push(...frame.bins);
      const oldest = bins[bins.length - 1].time_s - HOUR_S;
      while (bins.length && bins[0].time_s < oldest) bins.shift();
    }
    addEvents(frame.events);
    renderStatus(frame.status);
    if (document.getElementById("follow").checked) view.endS = null;
    requestDraw();
  };
}

start();
