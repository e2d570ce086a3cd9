// cryod's live page: the status as `cryod ctl status` gives it, pushed by the interfaces process (server-sent
// events), and the last hour in one-second bins drawn with uPlot (served from the package, like this file).
// Times on the charts are the lab's local time of day: the daemon's clock plus its offset to the wall clock.
"use strict";

const HOUR_S = 3600;
const FOLD_AT = 160;                       // characters of an event shown before it is folded
const view = { spanS: 600, follow: true };
let bins = [];
let clockOffsetS = 0;                      // wall clock (s since the epoch) at the daemon's clock time 0
let heaterMaxW = null;                     // R * I_max^2: the top of the heater chart
const charts = [];

// -- numbers ---------------------------------------------------------------------------------------
const FORMATS = {
  kelvin6: (v) => `${v.toFixed(6)} K`,
  kelvin4: (v) => `${v.toFixed(4)} K`,
  microkelvin: (v) => `${(v * 1e6 >= 0 ? "+" : "")}${(v * 1e6).toFixed(1)} µK`,
  microkelvin_unsigned: (v) => `${(v * 1e6).toFixed(1)} µK`,
  milliwatt: (v) => `${(v * 1e3).toFixed(3)} mW`,
  rate: (v) => (v === 0 ? "steps" : `${v} K/min`),
  ratio: (v) => `${(100 * v).toFixed(0)} %`,
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

// The lab's time of day, on a 24-hour clock whatever the browser's language (a lab's logbook is kept so).
function localTime(wallS, seconds = true) {
  return new Date(wallS * 1000).toLocaleTimeString([], { hour: "2-digit", minute: "2-digit", hourCycle: "h23",
                                                           ...(seconds ? { second: "2-digit" } : {}) });
}

function piPart(status) {
  if (status.pi_proportional_W === undefined) return null;
  return (status.pi_proportional_W ?? 0) + (status.pi_integral_W ?? 0);
}

function renderStatus(status) {
  const state = document.getElementById("state");
  state.textContent = status.state ?? "–";
  state.dataset.value = status.state ?? "";
  state.className = "state " + String(status.state ?? "").split(":")[0];
  for (const key of ["T2_K", "T2_average_K", "setpoint_K", "target_K", "ramp_K_per_min", "T5_K", "heater_W",
                     "heater_mean_W", "ff_W", "line_amplitude_K", "ff_limit_K", "time_s", "overruns",
                     "lateness_ms_p99"]) {
    show(key, status[key]);
  }
  show("error_K", status.T2_K != null && status.setpoint_K != null ? status.T2_K - status.setpoint_K : null);
  show("pi_W", piPart(status));
  show("last_fault", status.last_fault ?? "none");
  show("wall_time", status.time_s != null ? localTime(status.time_s + clockOffsetS) : null);
  const newest = bins.length ? bins[bins.length - 1] : null;
  show("ff_band", newest && newest.ff_min_W !== null
    ? `${(newest.ff_min_W * 1e3).toFixed(1)} to ${(newest.ff_max_W * 1e3).toFixed(1)} mW` : null);
  const ratio = status.line_amplitude_K != null && status.ff_limit_K ? status.line_amplitude_K / status.ff_limit_K
    : null;
  show("line_ratio", ratio);
  // the bar is full at the physical limit and half full at twice it: the line cannot go below the limit
  if (ratio !== null) document.getElementById("line_meter").value = Math.min(1, 1 / ratio);
  const faults = document.getElementById("faults");
  const faulted = String(status.state ?? "").startsWith("fault") || status.state === "stopped";
  faults.hidden = !(faulted || status.last_fault);
  faults.textContent = status.last_fault ? `last fault: ${status.last_fault}` : (faulted ? status.state : "");
  const warning = document.getElementById("setpoint_warning");
  warning.hidden = !status.setpoint_warning;
  warning.textContent = status.setpoint_warning ?? "";
  const alarms = document.getElementById("alarms");
  const raised = Array.isArray(status.alarms) ? status.alarms : [];
  alarms.hidden = raised.length === 0;
  alarms.replaceChildren(...raised.map((alarm) => {
    const item = document.createElement("li");
    item.textContent = alarmText(alarm);
    if (alarm.name) item.dataset.alarm = alarm.name;
    return item;
  }));
  if (status.record_path !== undefined) show("record_path", status.record_path);
}

// An alarm of the status: its name, raised or latched, acknowledged or not, and its figure when it was raised.
function alarmText(alarm) {
  if (typeof alarm === "string") return alarm;
  const acknowledged = alarm.acknowledged ? ", acknowledged" : "";
  return `${alarm.name} ${alarm.state}${acknowledged}: ${alarm.raised_message || alarm.message}`;
}

// -- notes and events: one list, newest first, long ones folded ------------------------------------
function eventItem(event) {
  const item = document.createElement("li");
  item.className = `event ${event.kind}`;
  const when = document.createElement("time");
  when.textContent = event.time_s === null ? "" : localTime(event.time_s + clockOffsetS);
  const kind = document.createElement("span");
  kind.className = "kind";
  kind.textContent = `${event.kind}: `;
  item.append(when, kind);
  if (event.message.length <= FOLD_AT) {
    item.append(event.message);
  } else {
    const folded = document.createElement("details");
    const summary = document.createElement("summary");
    summary.textContent = event.message.slice(0, FOLD_AT) + " …";
    const whole = document.createElement("p");
    whole.textContent = event.message;
    folded.append(summary, whole);
    item.append(folded);
  }
  return item;
}

function addEvents(events) {
  const list = document.getElementById("events");
  for (const event of events) list.prepend(eventItem(event));
  while (list.children.length > 200) list.lastChild.remove();
}

// -- charts ----------------------------------------------------------------------------------------
const mk = (v) => (v === null || v === undefined ? null : v * 1e3);
const uk = (v) => (v === null || v === undefined ? null : v * 1e6);
const diff = (a, b) => (a === null || b === null || a === undefined || b === undefined ? null : a - b);

// Each chart: its title, the unit of its axis, its series (label, colour, how a bin gives its value) and the
// bands filled between two of them (indexes into the series, counted from 1); its axis' range when uPlot's own
// (all the data in view) is not the one to read.
const CHARTS = [
  { id: "chart-T2", title: "T2 flange", unit: "K", digits: 5, series: [
      ["T2 lowest in each second", "#9ecae1", (b) => b.T2_min_K],
      ["T2 highest in each second", "#9ecae1", (b) => b.T2_max_K],
      ["T2 mean", "#1f77b4", (b) => b.T2_mean_K, 2],
      ["setpoint", "#d62728", (b) => b.setpoint_K, 1.5]], bands: [[2, 1, "rgba(31,119,180,0.18)"]] },
  { id: "chart-error", title: "T2 minus the setpoint", unit: "µK", digits: 1, range: settledRange, series: [
      ["lowest in each second", "#a1d99b", (b) => uk(diff(b.T2_min_K, b.setpoint_K))],
      ["highest in each second", "#a1d99b", (b) => uk(diff(b.T2_max_K, b.setpoint_K))],
      ["mean", "#2ca02c", (b) => uk(diff(b.T2_mean_K, b.setpoint_K)), 2]], bands: [[2, 1, "rgba(44,160,44,0.18)"]] },
  { id: "chart-heater", title: "Heater", unit: "mW", digits: 1, range: heaterRange, series: [
      ["heater, mean of the last 10 cooler cycles", "#e6550d", (b) => mk(b.heater_level_W), 2],
      ["waveform range: lowest", "#fdae6b", (b) => mk(b.heater_min_W)],
      ["waveform range: highest", "#fdae6b", (b) => mk(b.heater_max_W)],
      ["PI's part", "#8c564b", (b) => mk(b.pi_W), 1.5]], bands: [[3, 2, "rgba(253,174,107,0.25)"]] },
  { id: "chart-line", title: "Cooler line on T2 against its physical limit", unit: "µK", digits: 1, series: [
      ["line (all harmonics)", "#1f77b4", (b) => uk(b.line_amplitude_K), 2],
      ["physical limit", "#d62728", (b) => uk(b.line_limit_K), 1.5]], bands: [] },
  { id: "chart-T5", title: "T5 cooler stage", unit: "K", digits: 4, series: [
      ["T5 lowest in each second", "#c5b0d5", (b) => b.T5_min_K],
      ["T5 highest in each second", "#c5b0d5", (b) => b.T5_max_K],
      ["T5 mean", "#9467bd", (b) => b.T5_mean_K, 2]], bands: [[2, 1, "rgba(148,103,189,0.18)"]] },
];

// The heater's own range, from the waveform's lowest to R * I_max^2: PI's request beyond it (while the heater is
// held at its top) is not drawn as if it were heat.
function heaterRange(u, low, high) {
  const top = heaterMaxW === null ? high : 1.05 * heaterMaxW * 1e3;
  return [Math.min(0, low), Math.max(top, 1)];
}

// T2's error as it is once settled: the axis spans what the seconds in view reach, leaving out the most extreme
// 3 % at each end (a setpoint step's transient of tens of millikelvin would otherwise flatten a regulation of a few
// hundred microkelvin into a line); the title says so when something leaves the axis.
const SETTLED_QUANTILE = 0.03;
function settledRange(u, low, high) {
  const inView = (values) => values.filter((v, i) => v !== null && u.data[0][i] >= u.scales.x.min
                                                    && u.data[0][i] <= u.scales.x.max);
  const lows = inView(u.data[1]).sort((a, b) => a - b);
  const highs = inView(u.data[2]).sort((a, b) => a - b);
  if (lows.length < 20 || highs.length < 20) return [Math.min(low, -1), Math.max(high, 1)];
  const bottom = lows[Math.floor(SETTLED_QUANTILE * (lows.length - 1))];
  const top = highs[Math.ceil((1 - SETTLED_QUANTILE) * (highs.length - 1))];
  const pad = Math.max(0.15 * (top - bottom), 1);
  const range = [Math.min(bottom - pad, -pad), Math.max(top + pad, pad)];
  const clipped = lows[0] < range[0] || highs[highs.length - 1] > range[1];
  const title = u.root.querySelector(".u-title");
  if (title) title.textContent = `T2 minus the setpoint (µK)${clipped ? ": a transient leaves the axis" : ""}`;
  return range;
}

// Tick labels with as many decimals as the step between ticks needs (no "-40000.0 µK", no "5.24000 K").
function tickLabels(splits) {
  const step = splits.length > 1 ? Math.abs(splits[1] - splits[0]) : 0;
  let digits = 0;                          // the fewest decimals that write the step exactly (0.00025: 5)
  while (digits < 8 && step > 0 && Math.abs(step * 10 ** digits - Math.round(step * 10 ** digits)) > 1e-6) digits++;
  return splits.map((v) => v.toFixed(digits));
}

function chartData(chart) {
  const times = bins.map((b) => b.time_s + clockOffsetS);
  return [times, ...chart.series.map(([, , pick]) => bins.map((b) => { const v = pick(b); return v ?? null; }))];
}

function chartWidth(element) {
  return Math.max(320, element.clientWidth - 2);
}

function makeChart(chart) {
  const holder = document.createElement("figure");
  holder.id = chart.id;
  document.getElementById("charts").insertBefore(holder, document.getElementById("events-box"));     // the notes and events come last
  const options = {
    title: `${chart.title} (${chart.unit})`,
    width: chartWidth(holder),
    height: 230,
    cursor: { drag: { x: true, y: false } },
    scales: { x: { time: true }, ...(chart.range ? { y: { range: chart.range } } : {}) },
    axes: [
      { space: 90, grid: { stroke: "#eee" }, ticks: { stroke: "#ccc" },
        values: (u, splits) => {
          const span = u.scales.x.max - u.scales.x.min;
          const labels = splits.map((v) => localTime(v, span < 900));
          holder.dataset.timeAxis = labels.join(" ");   // what the axis shows, for a reader of the page's DOM
          return labels;
        } },
      { label: chart.unit, size: 70, grid: { stroke: "#eee" }, ticks: { stroke: "#ccc" },
        values: (u, splits) => tickLabels(splits) },
    ],
    series: [
      { label: "local time", value: (u, v) => (v === null ? "–" : localTime(v)) },
      ...chart.series.map(([label, colour, , width]) => ({
        label, stroke: colour, width: width ?? 1, spanGaps: false, points: { show: false },
        value: (u, v) => (v === null || v === undefined ? "–" : `${v.toFixed(chart.digits + 1)} ${chart.unit}`),
      })),
    ],
    bands: chart.bands.map(([high, low, fill]) => ({ series: [high, low], fill })),
    hooks: {
      setSelect: [(u) => {                 // a zoom by dragging: stop following the newest
        if (u.select.width > 0) {
          view.follow = false;
          document.getElementById("follow").checked = false;
        }
      }],
    },
  };
  const plot = new uPlot(options, chartData(chart), holder);
  holder.addEventListener("dblclick", () => {
    view.follow = true;
    document.getElementById("follow").checked = true;
    redraw();
  });
  charts.push({ chart, plot, holder });
}

// The window shown while following: the last spanS seconds, or all there is when the history is shorter.
function windowRange() {
  if (!bins.length) return null;
  const end = bins[bins.length - 1].time_s + 1 + clockOffsetS;
  return { min: Math.max(end - view.spanS, bins[0].time_s + clockOffsetS), max: end };
}

function redraw() {
  const range = windowRange();
  for (const { chart, plot } of charts) {
    plot.setData(chartData(chart), false);
    if (range && view.follow) plot.setScale("x", range);
    else plot.redraw();
  }
}

let redrawPending = false;
function requestRedraw() {
  if (!redrawPending) {
    redrawPending = true;
    requestAnimationFrame(() => { redrawPending = false; redraw(); });
  }
}

function resizeCharts() {
  for (const { plot, holder } of charts) plot.setSize({ width: chartWidth(holder), height: 230 });
}

// -- control (only when the daemon allows it) --------------------------------------------------------
async function sendCommand(line) {
  try {
    const response = await fetch("/api/command", {
      method: "POST",
      headers: { "Content-Type": "application/json", "X-Cryod-Token": document.getElementById("token").value },
      body: JSON.stringify({ command: line }),
    });
    const answer = await response.json();
    show("command_reply", `${line}: ${answer.ok ? "" : `refused (${response.status}): `}${answer.message}`);
    if (answer.status) renderStatus(answer.status);
  } catch (error) {
    show("command_reply", `${line}: not sent (${error})`);
  }
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
      view.follow = true;
      document.getElementById("follow").checked = true;
      redraw();
    });
  }
  document.getElementById("follow").addEventListener("change", (event) => {
    view.follow = event.target.checked;
    redraw();
  });
  const [status, history] = await Promise.all([fetch("/api/status").then((r) => r.json()),
                                               fetch("/api/history").then((r) => r.json())]);
  clockOffsetS = status.clock_offset_s ?? 0;
  heaterMaxW = status.heater_max_W ?? null;
  bins = history.bins;
  addEvents(history.events);
  renderStatus(status.status);
  setUpControl(status.page_commands);
  for (const chart of CHARTS) makeChart(chart);
  redraw();
  new ResizeObserver(resizeCharts).observe(document.getElementById("charts"));
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
      requestRedraw();
    }
    addEvents(frame.events);
    renderStatus(frame.status);
  };
}

start();
