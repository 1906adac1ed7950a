/* pgd view: the page. Every string from the codebook or a data file goes in as text (textContent,
 * attribute values); nothing is parsed as HTML. Charts are uPlot's; maps are images drawn into a
 * uPlot chart's plotting area (its axes, its cursor). */
"use strict";

(function () {
  const errors = [];
  const api = window.pgdView = {ready: false, errors: errors, timings: {}};
  window.addEventListener("error", (e) => errors.push(String(e.message || e)));

  const COLORS = ["#0072B2", "#D55E00", "#009E73", "#CC79A7", "#E69F00", "#56B4E9", "#000000"];
  const VIRIDIS = ["#440154", "#482878", "#3e4989", "#31688e", "#26828e", "#1f9e89", "#35b779", "#6ece58",
                   "#b5de2b", "#fde725"].map((h) => [1, 3, 5].map((i) => parseInt(h.substr(i, 2), 16)));
  const CURVE_SAMPLES = 400, LINE_SAMPLES = 200, MAP_X = 160, MAP_Y = 120, PLAY_SECONDS = 6;

  // ------------------------------------------------------------------ small helpers
  function el(tag, attrs, children) {
    const e = document.createElement(tag);
    for (const [k, v] of Object.entries(attrs || {})) {
      if (k === "text") e.textContent = v;
      else if (k === "class") e.className = v;
      else e.setAttribute(k, v);
    }
    for (const c of children || []) e.appendChild(typeof c === "string" ? document.createTextNode(c) : c);
    return e;
  }

  function fmt(v, digits) {
    if (v === null || v === undefined || !isFinite(v)) return "n/a";
    const a = Math.abs(v);
    if (a !== 0 && (a < 1e-3 || a >= 1e5)) return v.toExponential((digits || 4) - 1).replace("e+", "e");
    return String(Number(v.toPrecision(digits || 4)));
  }

  function linspace(lo, hi, n) {
    const out = new Float64Array(n);
    for (let i = 0; i < n; i++) out[i] = i === n - 1 ? hi : lo + (hi - lo) * i / (n - 1);
    return out;
  }

  function viridis(f) {
    const x = Math.min(Math.max(f, 0), 1) * (VIRIDIS.length - 1), i = Math.min(Math.floor(x), VIRIDIS.length - 2);
    const t = x - i, a = VIRIDIS[i], b = VIRIDIS[i + 1];
    return [0, 1, 2].map((c) => Math.round(a[c] + (b[c] - a[c]) * t));
  }

  function median(values) {
    const s = values.slice().sort((a, b) => a - b), n = s.length;
    return n % 2 ? s[(n - 1) / 2] : 0.5 * (s[n / 2 - 1] + s[n / 2]);
  }

  // ------------------------------------------------------------------ the model and its state
  const payload = JSON.parse(document.getElementById("pgd-data").textContent);
  const meta = payload.meta;
  const cb = new PgdEval.Codebook(payload.layout);
  const coords = cb.coordinates;
  const roles = meta.coordinates.map((c) => c.role);
  const timeIndex = roles.indexOf("time");
  const spaceIndex = roles.map((r, j) => (r === "space" ? j : -1)).filter((j) => j >= 0);
  const paramIndex = roles.map((r, j) => (r !== "time" && r !== "space" ? j : -1)).filter((j) => j >= 0);
  const axis = timeIndex >= 0 ? timeIndex : (spaceIndex.length ? spaceIndex[0] : 0);
  // start at the middle of every domain, rounded to 6 digits where that stays inside
  const xs = coords.map((c) => {
    const mid = 0.5 * (c.low + c.high), short = Number(mid.toPrecision(6));
    return short >= c.low && short <= c.high ? short : mid;
  });
  const state = {curves: true, map: true, data: null, field: 0, playing: false, colorRange: null};
  const controls = [];
  const charts = [];
  const readout = [];
  let fieldPanel = null, scheduled = false, command = null, timingText = null, mapMs = 0, mapQueued = false, lastCurvesMs = 0;

  // ------------------------------------------------------------------ controls
  function coordinateRow(j) {
    const c = coords[j], role = roles[j];
    const id = "coord-" + j;
    const label = el("label", {for: id + "-number", class: "name", text: c.name});
    const tag = el("span", {class: "role", text: role});
    const slider = el("input", {type: "range", id: id + "-slider", min: String(c.low), max: String(c.high),
                                step: String((c.high - c.low) / 1000), "aria-label": c.name});
    const number = el("input", {type: "number", id: id + "-number", min: String(c.low), max: String(c.high),
                                step: "any", class: "number"});
    const note = el("div", {class: "note", id: id + "-note"});
    const domain = el("span", {class: "domain", text: "[" + fmt(c.low, 6) + ", " + fmt(c.high, 6) + "]"});
    slider.setAttribute("data-coordinate", c.name);
    number.setAttribute("data-coordinate", c.name);
    slider.value = String(xs[j]);
    number.value = String(xs[j]);
    slider.addEventListener("input", () => {
      setValue(j, Number(slider.value), "slider");
    });
    number.addEventListener("change", () => {
      const v = Number(number.value);
      if (number.value.trim() === "" || !isFinite(v) || v < c.low || v > c.high) {
        note.textContent = c.name + " must be a number in [" + fmt(c.low, 8) + ", " + fmt(c.high, 8) + "]";
        number.classList.add("invalid");
        return;
      }
      setValue(j, v, "number");
    });
    controls[j] = {slider: slider, number: number, note: note};
    return el("div", {class: "coordinate"}, [el("div", {class: "head"}, [label, tag, domain]),
                                              el("div", {class: "inputs"}, [slider, number]), note]);
  }

  function setValue(j, v, source) {
    const c = controls[j];
    xs[j] = v;
    if (source !== "slider") c.slider.value = String(v);
    if (source !== "number") c.number.value = String(v);
    c.number.classList.remove("invalid");
    c.note.textContent = "";
    if (j !== axis) state.curves = true;
    if (fieldPanel && fieldPanel.depends(j)) {
      state.map = true;
      if (j !== timeIndex) state.colorRange = null;
    }
    schedule();
  }

  function schedule() {
    if (!scheduled) {
      scheduled = true;
      requestAnimationFrame(update);
    }
  }

  // ------------------------------------------------------------------ charts
  function chartWidth(container, columns) {
    /* the width of one of `columns` charts side by side in the container (8 px apart) */
    const w = (container.clientWidth || 800) - 2;
    return Math.max(240, Math.floor((w - 8 * (columns - 1)) / columns));
  }

  function cursorLine(value) {
    return (u) => {
      const v = value();
      if (v === null) return;
      const x = Math.round(u.valToPos(v, "x", true));
      const ctx = u.ctx;
      ctx.save();
      ctx.strokeStyle = "rgba(0,0,0,0.45)";
      ctx.setLineDash([4, 4]);
      ctx.lineWidth = 1;
      ctx.beginPath();
      ctx.moveTo(x, u.bbox.top);
      ctx.lineTo(x, u.bbox.top + u.bbox.height);
      ctx.stroke();
      ctx.restore();
    };
  }

  function lineChart(target, opts) {
    const series = [{label: opts.xLabel, value: (u, v) => (v === null ? "--" : fmt(v, 6))}, {
      label: opts.label, stroke: opts.color, width: 1.8, spanGaps: true, points: {show: false},
      value: (u, v) => (v === null ? "--" : fmt(v, 6))}];
    const u = new uPlot({
      width: opts.width, height: opts.height || 220, title: opts.title,
      scales: {x: {time: false}},
      axes: [{label: opts.xLabel}, {label: opts.yLabel, size: 64}],
      series: series,
      cursor: {drag: {x: true, y: false}},
      hooks: {draw: [cursorLine(opts.marker)],
              // a zoom (drag across the chart; double-click: all) outlives the curves' updates
              setScale: [(u, key) => {
                const x = u.data[0];
                if (key !== "x" || u.restoring || !x.length) return;
                const s = u.scales.x, full = s.min <= x[0] && s.max >= x[x.length - 1];
                u.zoom = full ? null : [s.min, s.max];
              }]},
    }, [[], []], target);
    u.hasData = false;
    u.zoom = null;
    return u;
  }

  function setDataSeries(u, x, y, points) {
    /* the codebook's curve, and data points (markers) when given */
    if (points && !u.hasData) {
      u.addSeries({label: points.label, stroke: "#222", fill: "#222", paths: () => null,
                   points: {show: true, size: 7, width: 1, fill: "#222", stroke: "#222"}});
      u.hasData = true;
    } else if (!points && u.hasData) {
      u.delSeries(2);
      u.hasData = false;
    }
    u.restoring = true;
    u.setData(points ? uPlot.join([[x, y], [points.x, points.y]]) : [x, y]);
    if (u.zoom) u.setScale("x", {min: u.zoom[0], max: u.zoom[1]});
    u.restoring = false;
  }

  function heatChart(target, opts) {
    /* a uPlot chart whose plotting area shows an image of values (row-major, x fastest, y from the bottom) */
    const image = document.createElement("canvas");
    const u = new uPlot({
      width: opts.width, height: opts.height || 260, title: opts.title,
      scales: {x: {time: false, auto: false, range: [opts.x.low, opts.x.high]},
               y: {auto: false, range: [opts.y.low, opts.y.high]}},
      axes: [{label: opts.x.name}, {label: opts.y.name, size: 64}],
      series: [{label: opts.x.name, value: (u, v) => (v === null ? "--" : fmt(v, 5))},
               {label: opts.label, stroke: "rgba(0,0,0,0)", points: {show: false}}],
      legend: {show: false},
      cursor: {drag: {x: false, y: false}, points: {show: false}},
      hooks: {
        drawClear: [(u) => {
          if (!image.width) return;
          u.ctx.save();
          u.ctx.imageSmoothingEnabled = true;
          u.ctx.drawImage(image, u.bbox.left, u.bbox.top, u.bbox.width, u.bbox.height);
          u.ctx.restore();
        }],
        draw: [(u) => {
          const ctx = u.ctx, px = opts.markerX(), py = opts.markerY();
          ctx.save();
          ctx.strokeStyle = "rgba(255,255,255,0.85)";
          ctx.lineWidth = 1;
          ctx.setLineDash([4, 3]);
          ctx.beginPath();
          if (px !== null) {
            const x = Math.round(u.valToPos(px, "x", true));
            ctx.moveTo(x, u.bbox.top);
            ctx.lineTo(x, u.bbox.top + u.bbox.height);
          }
          if (py !== null) {
            const y = Math.round(u.valToPos(py, "y", true));
            ctx.moveTo(u.bbox.left, y);
            ctx.lineTo(u.bbox.left + u.bbox.width, y);
          }
          ctx.stroke();
          ctx.restore();
        }],
      },
    }, [[opts.x.low, opts.x.high], [null, null]], target);
    u.paint = (values, nx, ny, lo, hi) => {
      image.width = nx;
      image.height = ny;
      const g = image.getContext("2d"), img = g.createImageData(nx, ny), span = hi > lo ? hi - lo : 1;
      for (let j = 0; j < ny; j++) {
        for (let i = 0; i < nx; i++) {
          const rgb = viridis((values[(ny - 1 - j) * nx + i] - lo) / span), o = 4 * (j * nx + i);
          img.data[o] = rgb[0];
          img.data[o + 1] = rgb[1];
          img.data[o + 2] = rgb[2];
          img.data[o + 3] = 255;
        }
      }
      g.putImageData(img, 0, 0);
      u.redraw(false, false);
    };
    return u;
  }

  function colorBar(target) {
    const bar = el("canvas", {class: "colorbar", width: "256", height: "12"});
    const g = bar.getContext("2d");
    for (let i = 0; i < 256; i++) {
      const rgb = viridis(i / 255);
      g.fillStyle = "rgb(" + rgb.join(",") + ")";
      g.fillRect(i, 0, 1, 12);
    }
    const low = el("span", {class: "cb-low"}), high = el("span", {class: "cb-high"});
    target.appendChild(el("div", {class: "colorbar-row"}, [low, bar, high]));
    return (lo, hi) => {
      low.textContent = fmt(lo, 4);
      high.textContent = fmt(hi, 4);
    };
  }

  function range(values) {
    let lo = Infinity, hi = -Infinity;
    for (const v of values) {
      if (v < lo) lo = v;
      if (v > hi) hi = v;
    }
    if (!(hi > lo)) {
      const pad = Math.abs(lo) > 0 ? Math.abs(lo) * 1e-6 : 1e-12;
      return [lo - pad, hi + pad];
    }
    return [lo, hi];
  }

  // ------------------------------------------------------------------ the field over space
  function makeFieldPanel(target) {
    if (!spaceIndex.length) return null;
    const sx = spaceIndex[0];
    const second = timeIndex >= 0 && spaceIndex.length === 1 ? timeIndex : (spaceIndex.length > 1 ? spaceIndex[1] : -1);
    if (second < 0) return null;  // steady, one space coordinate: the curves are already over space
    const panel = el("section", {class: "panel field"});
    const heading = el("h2", {text: "Field over space"});
    const select = el("select", {id: "field-select", "aria-label": "unknown shown over space"});
    cb.unknowns.forEach((u, i) => select.appendChild(el("option", {value: String(i), text: u})));
    select.addEventListener("change", () => {
      state.field = Number(select.value);
      state.map = true;
      state.colorRange = null;
      schedule();
    });
    panel.appendChild(heading);
    panel.appendChild(el("div", {class: "field-select"}, [el("label", {for: "field-select", text: "unknown "}), select]));
    const row = el("div", {class: "field-row"});
    panel.appendChild(row);
    target.appendChild(panel);
    const width = chartWidth(row, second === timeIndex ? 2 : 1);
    const withTime = second === timeIndex;
    const lineBox = el("div"), mapBox = el("div");
    if (withTime) row.appendChild(lineBox);
    row.appendChild(mapBox);
    const cx = coords[sx], cy = coords[second];
    const line = withTime ? lineChart(lineBox, {width: width, xLabel: cx.name, yLabel: "", label: "value",
                                                title: " ", color: COLORS[0], marker: () => xs[sx]}) : null;
    const heat = heatChart(mapBox, {width: withTime ? width : Math.min(width, 640), height: withTime ? 220 : 360,
                                    x: cx, y: cy, label: "", title: " ",
                                    markerX: () => xs[sx], markerY: () => xs[second]});
    const setBar = colorBar(mapBox);
    const samplesX = linspace(cx.low, cx.high, withTime ? LINE_SAMPLES : MAP_X);
    const mapX = linspace(cx.low, cx.high, MAP_X), mapY = linspace(cy.low, cy.high, MAP_Y);
    const view = {
      line: line, heat: heat,
      depends: (j) => j !== sx && (withTime ? j !== timeIndex : j !== second),
      resize: () => {
        const w = chartWidth(row, withTime ? 2 : 1);
        if (line) line.setSize({width: w, height: 220});
        heat.setSize({width: withTime ? w : Math.min(w, 640), height: withTime ? 220 : 360});
      },
      update: (mapChanged) => {
        const name = cb.unknowns[state.field];
        if (line) {
          const curve = cb.curves(xs, sx, samplesX)[state.field];
          setDataSeries(line, Array.from(samplesX), Array.from(curve), null);
          line.root.querySelector(".u-title") && (line.root.querySelector(".u-title").textContent =
            name + " over " + cx.name + " at " + coords[timeIndex].name + " = " + fmt(xs[timeIndex], 5));
        }
        if (mapChanged || !withTime) {
          const values = cb.map(state.field, xs, second, sx, mapY, mapX);  // rows: y, columns: x
          let [lo, hi] = range(values);
          if (!withTime && timeIndex >= 0) {
            // a colour scale fixed over time, so that an animation compares like with like
            if (!state.colorRange) state.colorRange = colorRangeOverTime(sx, second);
            [lo, hi] = state.colorRange;
          }
          heat.paint(values, MAP_X, MAP_Y, lo, hi);
          setBar(lo, hi);
          const title = heat.root.querySelector(".u-title");
          if (title) title.textContent = name + (withTime ? " over " + cx.name + " and " + cy.name
                                                     : (timeIndex >= 0 ? " at " + coords[timeIndex].name + " = " +
                                                        fmt(xs[timeIndex], 5) : ""));
        }
        heat.redraw(false, false);
      },
    };
    return view;
  }

  function colorRangeOverTime(sx, sy) {
    /* the field's range over space at 9 times, on a grid a quarter as fine as the image's (a scale, not a value) */
    const saved = xs[timeIndex], c = coords[timeIndex];
    const gx = linspace(coords[sx].low, coords[sx].high, MAP_X / 4 + 1), gy = linspace(coords[sy].low, coords[sy].high,
                                                                                        MAP_Y / 4 + 1);
    let lo = Infinity, hi = -Infinity;
    for (const t of linspace(c.low, c.high, 9)) {
      xs[timeIndex] = t;
      const [a, b] = range(cb.map(state.field, xs, sy, sx, gy, gx));
      lo = Math.min(lo, a);
      hi = Math.max(hi, b);
    }
    xs[timeIndex] = saved;
    return [lo, hi];
  }

  // ------------------------------------------------------------------ data (pgd fit's CSV)
  function parseCSV(text, label) {
    const lines = text.replace(/^\ufeff/, "").split(/\r\n|\n|\r/).filter((l) => l.trim() !== "");
    if (!lines.length) throw new Error(label + ": empty file (expected a CSV header naming the columns)");
    const split = (line) => line.split(",").map((s) => s.trim().replace(/^"(.*)"$/, "$1"));
    const header = split(lines[0]);
    if (header.some((h) => !h) || new Set(header).size !== header.length)
      throw new Error(label + ": the header must name every column once, got " + header.join(","));
    if (lines.length === 1) throw new Error(label + ": no data rows after the header");
    const columns = {};
    header.forEach((h) => (columns[h] = []));
    lines.slice(1).forEach((line, i) => {
      const row = split(line);
      if (row.length !== header.length)
        throw new Error(label + ": line " + (i + 2) + " has " + row.length + " values for " + header.length + " columns");
      row.forEach((s, k) => {
        const v = Number(s);
        if (s === "" || !isFinite(v))
          throw new Error(label + ": line " + (i + 2) + ", column " + JSON.stringify(header[k]) + ": " +
                          JSON.stringify(s) + " is not a finite number");
        columns[header[k]].push(v);
      });
    });
    return {label: label, columns: columns};
  }

  function checkData(data) {
    const names = coords.map((c) => c.name), unknowns = cb.unknowns, label = data.label;
    const observed = [], notes = [];
    for (const [name, col] of Object.entries(data.columns)) {
      const j = names.indexOf(name);
      if (j >= 0) {
        const bad = col.find((v) => v < coords[j].low || v > coords[j].high);
        if (bad !== undefined)
          throw new Error(label + ": column " + JSON.stringify(name) + ": value " + bad + " is outside the domain [" +
                          fmt(coords[j].low, 8) + ", " + fmt(coords[j].high, 8) + "]");
      } else if (unknowns.indexOf(name) >= 0) {
        observed.push(name);
      } else if (!(name.startsWith("sigma_") && unknowns.indexOf(name.slice(6)) >= 0)) {
        throw new Error(label + ": column " + JSON.stringify(name) + " is neither a coordinate (" + names.join(", ") +
                        "), an unknown (" + unknowns.join(", ") + ") nor sigma_<unknown>");
      }
    }
    const along = names[axis];
    if (!(along in data.columns)) throw new Error(label + ": no column for " + JSON.stringify(along));
    if (!observed.length) throw new Error(label + ": no observed unknown; add a column named one of " + unknowns.join(", "));
    for (const [name, col] of Object.entries(data.columns)) {
      const j = names.indexOf(name);
      if (j < 0 || j === axis) continue;
      if (col.every((v) => v === col[0])) {
        setValue(j, col[0], "data");
        notes.push(name + " = " + fmt(col[0], 8) + " from the data");
      } else {
        notes.push(name + " varies between rows: the curves are drawn at the slider's value");
      }
    }
    return {observed: observed, notes: notes};
  }

  function applyData(read, message) {
    /* read() gives {label, columns} (or throws): drawn as markers, or one line saying what is wrong */
    try {
      const data = read();
      const checked = checkData(data);
      const t = data.columns[coords[axis].name];
      state.data = {};
      for (const u of checked.observed) {
        const order = t.map((v, i) => i).sort((a, b) => t[a] - t[b]);
        state.data[u] = {label: data.label, x: order.map((i) => t[i]), y: order.map((i) => data.columns[u][i])};
      }
      message.className = "message";
      message.textContent = data.label + ": " + t.length + " rows of " + checked.observed.join(", ") +
        " (markers)" + (checked.notes.length ? "; " + checked.notes.join("; ") : "");
    } catch (e) {
      state.data = null;
      message.className = "message error";
      message.textContent = String(e.message || e);
    }
    state.curves = true;
    schedule();
  }

  function dataSection() {
    const input = el("input", {type: "file", id: "data-file", accept: ".csv,text/csv"});
    const clear = el("button", {type: "button", id: "data-clear", text: "Clear"});
    const message = el("div", {class: "message", id: "data-message"});
    input.addEventListener("change", () => {
      const file = input.files && input.files[0];
      if (!file) return;
      const reader = new FileReader();
      reader.onload = () => applyData(() => parseCSV(String(reader.result), file.name), message);
      reader.onerror = () => {
        message.className = "message error";
        message.textContent = file.name + ": cannot read the file";
      };
      reader.readAsText(file);
    });
    clear.addEventListener("click", () => {
      state.data = null;
      input.value = "";
      message.className = "message";
      message.textContent = "";
      state.curves = true;
      schedule();
    });
    api.loadData = (text, label) => applyData(() => parseCSV(text, label || "data.csv"), message);
    if (payload.data) setTimeout(() => applyData(() => payload.data, message), 0);
    return el("section", {class: "panel"}, [
      el("h2", {text: "Data"}),
      el("p", {class: "hint", text: "A CSV in pgd fit's format (a column for " + coords[axis].name +
                                    ", columns named after unknowns) is drawn as markers. It stays in this browser."}),
      el("div", {class: "inputs"}, [input, clear]), message]);
  }

  // ------------------------------------------------------------------ the codebook's facts
  function infoSection() {
    const rows = [];
    const table = el("table", {class: "facts"});
    const head = el("tr", {}, ["coordinate", "role", "domain", "nodes", "basis"].map((h) => el("th", {text: h})));
    table.appendChild(head);
    meta.coordinates.forEach((c) => {
      const basis = c.discretization + (c.elements ? ", " + c.elements + " elements" :
                                        (c.breakpoints && c.breakpoints.length > 2 ? ", " + (c.breakpoints.length - 1) + " slabs" : ""));
      table.appendChild(el("tr", {}, [c.name, c.role, "[" + fmt(c.domain[0], 6) + ", " + fmt(c.domain[1], 6) + "]",
                                      String(c.nodes), basis].map((v) => el("td", {text: v}))));
    });
    rows.push(table);
    const unknowns = el("table", {class: "facts"});
    unknowns.appendChild(el("tr", {}, ["unknown", "representation", "rank", "numbers"].map((h) => el("th", {text: h}))));
    for (const [name, u] of Object.entries(meta.unknowns || {})) {
      const rank = u.ranks ? u.ranks.join("-") : String(u.modes);
      unknowns.appendChild(el("tr", {}, [name, u.representation, rank, String(u.floats)].map((v) => el("td", {text: v}))));
    }
    rows.push(unknowns);
    const dl = el("dl", {class: "report"});
    const item = (k, v) => {
      dl.appendChild(el("dt", {text: k}));
      dl.appendChild(el("dd", {text: v}));
    };
    item("tolerance", fmt(meta.tolerance, 3) + (meta.relative_tolerance ? " + " + fmt(meta.relative_tolerance, 3) + " |u|" : ""));
    if (meta.check) {
      item("measured error", fmt(meta.check.error, 3) + " (max abs, " + meta.check.points + " points" +
           (meta.check.where ? ", largest at " + meta.check.where : "") + ")");
      if (meta.check.method) item("measured by", meta.check.method);
    }
    item("solver", String(meta.method || "") + (meta.steps ? ", " + meta.steps + " steps" : ""));
    if (meta.message) item("message", meta.message);
    if (meta.created) item("created", meta.created + (meta.pgdcli_version ? " by pgdcli " + meta.pgdcli_version : ""));
    rows.push(dl);
    return el("section", {class: "panel info"}, [el("h2", {text: "Codebook"})].concat(rows));
  }

  function status() {
    const tol = fmt(meta.tolerance, 3);
    if (meta.accurate === true)
      return el("p", {class: "status ok", id: "status",
                      text: "Within its tolerance " + tol + ": measured max error " + fmt(meta.check && meta.check.error, 3) +
                            " against an independent reference."});
    if (meta.accurate === false)
      return el("p", {class: "status bad", id: "status",
                      text: "Misses its tolerance " + tol + " (measured " + fmt(meta.check && meta.check.error, 3) +
                            "): written with --keep-inaccurate. Do not trust it to that tolerance."});
    return el("p", {class: "status unknown", id: "status", text: "Tolerance " + tol + "; the error was not measured."});
  }

  // ------------------------------------------------------------------ the readout
  function readoutSection() {
    const table = el("table", {class: "readout", id: "readout"});
    table.appendChild(el("tr", {}, [el("th", {text: "unknown"}), el("th", {text: "value at this point"})]));
    cb.unknowns.forEach((u, i) => {
      const cell = el("td", {class: "value", id: "value-" + i});
      cell.setAttribute("data-unknown", u);
      readout.push(cell);
      table.appendChild(el("tr", {}, [el("td", {text: u}), cell]));
    });
    command = el("code", {id: "command"});
    timingText = el("p", {class: "hint", id: "timing"});
    return el("section", {class: "panel"}, [el("h2", {text: "Values"}), table,
      el("p", {class: "hint", text: "The same numbers as:"}), command, timingText]);
  }

  function commandLine() {
    const source = meta.source || "CODEBOOK";
    return "pgd query " + source + coords.map((c, j) => " --" + c.name + " " + String(xs[j])).join("");
  }

  // ------------------------------------------------------------------ update
  const samples = linspace(coords[axis].low, coords[axis].high, CURVE_SAMPLES);
  const sampleArray = Array.from(samples);

  function update() {
    scheduled = false;
    const start = performance.now();
    let curvesMs = null;
    if (state.curves) {
      const t0 = performance.now();
      const values = cb.curves(xs, axis, samples);
      curvesMs = performance.now() - t0;
      charts.forEach((u, i) => setDataSeries(u, sampleArray, Array.from(values[i]), state.data && state.data[cb.unknowns[i]]));
      state.curves = false;
      api.lastCurves = {axis: coords[axis].name, samples: sampleArray, values: values.map((v) => Array.from(v))};
    } else {
      charts.forEach((u) => u.redraw(false, false));
    }
    const values = cb.point(xs);
    values.forEach((v, i) => (readout[i].textContent = String(v)));
    command.textContent = commandLine();
    if (fieldPanel) {
      // a map that took longer than a frame is redrawn just after this frame: the sliders stay live
      if (state.map && mapMs > 12) {
        fieldPanel.update(false);
        if (!mapQueued) {
          mapQueued = true;
          setTimeout(() => {
            mapQueued = false;
            const t0 = performance.now();
            fieldPanel.update(true);
            mapMs = performance.now() - t0;
          }, 0);
        }
      } else if (!mapQueued) {
        const t0 = performance.now();
        fieldPanel.update(state.map);
        if (state.map) mapMs = performance.now() - t0;
      }
      state.map = false;
    }
    const total = performance.now() - start;
    if (curvesMs !== null) lastCurvesMs = curvesMs;
    api.timings = {curves: curvesMs, update: total, map: mapMs};
    timingText.textContent = "Curves of " + CURVE_SAMPLES + " samples recomputed in " + lastCurvesMs.toFixed(2) +
                             " ms after the last parameter move; page updated in " + total.toFixed(1) + " ms.";
  }

  function play(button) {
    if (timeIndex < 0) return;
    const c = coords[timeIndex];
    let last = null;
    const step = (now) => {
      if (!state.playing) return;
      if (last !== null) {
        let t = xs[timeIndex] + (c.high - c.low) * (now - last) / 1000 / PLAY_SECONDS;
        if (t > c.high) t = c.low;
        setValue(timeIndex, t, "play");
      }
      last = now;
      requestAnimationFrame(step);
    };
    state.playing = !state.playing;
    button.textContent = state.playing ? "Pause" : "Play";
    if (state.playing) requestAnimationFrame(step);
  }

  // ------------------------------------------------------------------ the page
  function build() {
    const app = document.getElementById("app");
    const header = el("header", {}, [el("h1", {text: meta.name || cb.name})]);
    if (meta.description) header.appendChild(el("p", {class: "description", text: meta.description}));
    header.appendChild(status());
    app.appendChild(header);
    const aside = el("aside", {class: "controls"});
    const main = el("main", {class: "plots"});
    app.appendChild(el("div", {class: "layout"}, [aside, main]));
    if (paramIndex.length) {
      aside.appendChild(el("section", {class: "panel"}, [el("h2", {text: "Parameters"})].concat(paramIndex.map(coordinateRow))));
    }
    const probe = [timeIndex].concat(spaceIndex).filter((j) => j >= 0);
    if (probe.length) {
      const section = el("section", {class: "panel"}, [el("h2", {text: timeIndex >= 0 ? "Time and space" : "Space"})]
                                                           .concat(probe.map(coordinateRow)));
      if (timeIndex >= 0) {
        const button = el("button", {type: "button", id: "play", text: "Play"});
        button.addEventListener("click", () => play(button));
        section.appendChild(button);
      }
      aside.appendChild(section);
    }
    aside.appendChild(readoutSection());
    aside.appendChild(dataSection());
    const curves = el("section", {class: "panel"}, [el("h2", {text: "Unknowns over " + coords[axis].name})]);
    const grid = el("div", {class: "grid"});
    curves.appendChild(grid);
    main.appendChild(curves);
    const columns = cb.unknowns.length > 1 ? 2 : 1;
    const others = coords.map((c, j) => j).filter((j) => j !== axis);
    cb.unknowns.forEach((u, i) => {
      const box = el("div", {class: "chart"});
      grid.appendChild(box);
      charts.push(lineChart(box, {width: chartWidth(grid, columns), xLabel: coords[axis].name, yLabel: u, label: u,
                                  title: u, color: COLORS[i % COLORS.length], marker: () => xs[axis]}));
    });
    if (!others.length) grid.appendChild(el("p", {class: "hint", text: "This codebook has a single coordinate."}));
    fieldPanel = makeFieldPanel(main);
    main.appendChild(infoSection());
    app.appendChild(el("footer", {text: "Made by pgd view" + (meta.pgdcli_version ? " (pgdcli " + meta.pgdcli_version + ")" : "") +
                                       ". Evaluated in this page from the codebook's numbers; nothing is sent anywhere. " +
                                       "Charts: uPlot (MIT licence)."}));
    window.addEventListener("resize", () => {
      charts.forEach((u) => u.setSize({width: chartWidth(grid, columns), height: 220}));
      if (fieldPanel) fieldPanel.resize();
    });
  }

  // ------------------------------------------------------------------ for tests and benchmarks
  api.codebook = cb;
  api.charts = charts;
  api.point = () => Object.fromEntries(coords.map((c, j) => [c.name, xs[j]]));
  api.evaluate = (point) => {
    const values = cb.point(coords.map((c) => {
      if (!(c.name in point)) throw new Error("missing coordinate " + c.name);
      return point[c.name];
    }));
    return Object.fromEntries(cb.unknowns.map((u, i) => [u, values[i]]));
  };
  api.set = (name, value) => setValue(coords.findIndex((c) => c.name === name), value, "api");
  api.bench = (repeats) => {
    /* milliseconds after a parameter move: the curves' recomputation (every unknown, 400 samples; median and
       least of the blocks of ten), the page's update without the map, and the map over space (null
       without one), medians */
    const curves = [], updates = [], maps = [];
    const j = paramIndex.length ? paramIndex[0] : (axis === 0 && coords.length > 1 ? 1 : 0);
    const c = coords[j], saved = xs[j], slow = mapMs;
    mapMs = Infinity;  // the update leaves the map to later: it is timed on its own below
    for (let k = 0; k < (repeats || 50); k++) {
      xs[j] = c.low + (c.high - c.low) * ((k * 0.618034) % 1);
      let t0 = performance.now();
      for (let r = 0; r < 10; r++) cb.curves(xs, axis, samples);  // ten: the browser's clock ticks in 0.1 ms
      curves.push((performance.now() - t0) / 10);
      curves.least = Math.min(curves.least === undefined ? Infinity : curves.least, curves[curves.length - 1]);
      state.curves = state.map = true;
      t0 = performance.now();
      update();
      updates.push(performance.now() - t0);
      if (fieldPanel) {
        t0 = performance.now();
        fieldPanel.update(true);
        maps.push(performance.now() - t0);
      }
    }
    xs[j] = saved;
    mapMs = slow;
    state.curves = state.map = true;
    update();
    return {curves: median(curves), curvesLeast: curves.least, update: median(updates),
            map: maps.length ? median(maps) : null, samples: CURVE_SAMPLES, unknowns: cb.unknowns.length};
  };

  try {
    build();
    update();
    api.ready = true;
  } catch (e) {
    errors.push(String(e && e.stack || e));
    const app = document.getElementById("app");
    app.appendChild(el("p", {class: "status bad", text: "This page could not start: " + String(e.message || e)}));
  }
})();
