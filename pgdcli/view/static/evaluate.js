/* pgd view: the codebook's evaluator, written from the JSON export's rules (docs/export.md).
 *
 * Per coordinate the cardinal weights of a value on its window of nodes (Chebyshev: barycentric
 * weights on the slab holding the value, a unit weight at a node; linear elements: 1 - theta,
 * theta), then the CP sum or the tensor-train product. A point is contracted as `pgd query` does
 * it; curves and maps contract every other coordinate once, to the nodal values along the free
 * one(s), and interpolate those at every sample (one window a sample).
 */
"use strict";

var PgdEval = (function () {
  const ONE = new Float64Array([1]);

  function upperBound(sorted, x) {  // first index whose value is > x
    let lo = 0, hi = sorted.length;
    while (lo < hi) {
      const mid = (lo + hi) >> 1;
      if (sorted[mid] <= x) lo = mid + 1; else hi = mid;
    }
    return lo;
  }

  class Coordinate {
    constructor(c) {
      this.name = c.name;
      this.kind = c.kind;
      this.low = c.domain[0];
      this.high = c.domain[1];
      this.nodes = Float64Array.from(c.nodes);
      this.n = this.nodes.length;
      this.index = new Map();
      this.nodes.forEach((v, k) => this.index.set(v, k));
      if (this.kind === "chebyshev") {
        this.breaks = Float64Array.from(c.breakpoints);
        this.m = c.slab_size;
        this.bary = Float64Array.from(c.bary);
      } else if (this.kind !== "linear") {
        throw new Error("unknown discretization " + JSON.stringify(c.kind) + " of coordinate " + c.name);
      }
    }

    clamp(x) {
      return x < this.low ? this.low : (x > this.high ? this.high : x);
    }

    /* {lo, w}: the value's row is w (normalized) on nodes lo .. lo + w.length - 1 */
    window(x) {
      const k = this.index.get(x);
      if (k !== undefined) return {lo: k, w: ONE};
      const nodes = this.nodes;
      if (this.kind === "linear") {
        const left = Math.min(Math.max(upperBound(nodes, x) - 1, 0), this.n - 2);
        const theta = (x - nodes[left]) / (nodes[left + 1] - nodes[left]);
        return {lo: left, w: new Float64Array([1 - theta, theta])};
      }
      const slabs = this.breaks.length - 1, m = this.m;
      const s = Math.min(Math.max(upperBound(this.breaks, x) - 1, 0), slabs - 1);
      const lo = s * (m - 1), w = new Float64Array(m);
      let sum = 0;
      for (let i = 0; i < m; i++) {
        w[i] = this.bary[i] / (x - nodes[lo + i]);
        sum += w[i];
      }
      for (let i = 0; i < m; i++) w[i] /= sum;
      return {lo: lo, w: w};
    }

    /* the windows of samples, kept for the next call with the same array (a curve's samples do not move) */
    windowsOf(xs) {
      this.kept = this.kept || new WeakMap();
      let wins = this.kept.get(xs);
      if (!wins) {
        wins = Array.from(xs, (x) => this.window(this.clamp(x)));
        this.kept.set(xs, wins);
      }
      return wins;
    }

    /* nodal values (n) at the samples xs */
    interpolate(values, xs, out) {
      const wins = this.windowsOf(xs);
      out = out || new Float64Array(xs.length);
      for (let p = 0; p < xs.length; p++) {
        const w = wins[p].w, lo = wins[p].lo;
        let s = 0;
        for (let i = 0; i < w.length; i++) s += w[i] * values[lo + i];
        out[p] = s;
      }
      return out;
    }
  }

  /* CP: sum_r alphas[r] prod_j (w_j . modes_j[:, r]) */
  class CPField {
    constructor(u) {
      this.name = u.name;
      this.R = u.rank;
      this.alphas = Float64Array.from(u.alphas);
      this.modes = u.modes.map((m) => Float64Array.from(m));
    }

    size() {
      return this.alphas.length + this.modes.reduce((s, m) => s + m.length, 0);
    }

    /* (w . modes_j[:, r]) for every r */
    values(j, win, out) {
      const R = this.R, modes = this.modes[j], w = win.w, lo = win.lo;
      out.fill(0);
      for (let i = 0; i < w.length; i++) {
        const wi = w[i], base = (lo + i) * R;
        for (let r = 0; r < R; r++) out[r] += wi * modes[base + r];
      }
      return out;
    }

    point(wins) {
      const R = this.R, prod = new Float64Array(R), vals = new Float64Array(R);
      this.values(0, wins[0], prod);
      for (let j = 1; j < wins.length; j++) {
        this.values(j, wins[j], vals);
        for (let r = 0; r < R; r++) prod[r] *= vals[r];
      }
      let s = 0;
      for (let r = 0; r < R; r++) s += prod[r] * this.alphas[r];
      return s;
    }

    /* alphas times the product of the fixed coordinates' values */
    weights(wins, free) {
      const R = this.R, c = Float64Array.from(this.alphas), vals = new Float64Array(R);
      for (let j = 0; j < wins.length; j++) {
        if (free.indexOf(j) >= 0) continue;
        this.values(j, wins[j], vals);
        for (let r = 0; r < R; r++) c[r] *= vals[r];
      }
      return c;
    }

    nodal1(wins, j) {
      const R = this.R, c = this.weights(wins, [j]), modes = this.modes[j];
      const n = modes.length / R, out = new Float64Array(n);
      for (let a = 0; a < n; a++) {
        let s = 0;
        for (let r = 0; r < R; r++) s += modes[a * R + r] * c[r];
        out[a] = s;
      }
      return out;
    }

    nodal2(wins, j, k) {
      const R = this.R, c = this.weights(wins, [j, k]), mj = this.modes[j], mk = this.modes[k];
      const nj = mj.length / R, nk = mk.length / R, out = new Float64Array(nj * nk), row = new Float64Array(R);
      for (let a = 0; a < nj; a++) {
        for (let r = 0; r < R; r++) row[r] = mj[a * R + r] * c[r];
        for (let b = 0; b < nk; b++) {
          let s = 0;
          for (let r = 0; r < R; r++) s += row[r] * mk[b * R + r];
          out[a * nk + b] = s;
        }
      }
      return out;
    }
  }

  /* tensor train: [1] times, core by core, sum_k w_k core[:, lo + k, :] */
  class TTField {
    constructor(u) {
      this.name = u.name;
      this.order = u.mode_order.slice();
      this.shapes = u.shapes.map((s) => s.slice());
      this.cores = u.cores.map((c) => Float64Array.from(c));
      this.position = new Map();
      this.order.forEach((j, k) => this.position.set(j, k));
    }

    size() {
      return this.cores.reduce((s, c) => s + c.length, 0);
    }

    /* row vector v (r0) times the core at the window: (r1) */
    left(k, v, win) {
      const [r0, n, r1] = this.shapes[k], core = this.cores[k], out = new Float64Array(r1), w = win.w, lo = win.lo;
      for (let a = 0; a < r0; a++) {
        const va = v[a];
        if (va === 0) continue;
        for (let i = 0; i < w.length; i++) {
          const coef = va * w[i], base = (a * n + lo + i) * r1;
          for (let b = 0; b < r1; b++) out[b] += coef * core[base + b];
        }
      }
      return out;
    }

    /* the core at the window times column vector v (r1): (r0) */
    right(k, v, win) {
      const [r0, n, r1] = this.shapes[k], core = this.cores[k], out = new Float64Array(r0), w = win.w, lo = win.lo;
      for (let a = 0; a < r0; a++) {
        let s = 0;
        for (let i = 0; i < w.length; i++) {
          const base = (a * n + lo + i) * r1;
          let t = 0;
          for (let b = 0; b < r1; b++) t += core[base + b] * v[b];
          s += w[i] * t;
        }
        out[a] = s;
      }
      return out;
    }

    point(wins) {
      let v = ONE;
      for (let k = 0; k < this.order.length; k++) v = this.left(k, v, wins[this.order[k]]);
      return v[0];
    }

    /* left vector through cores [0, p), right vector through cores (q, d) */
    ends(wins, p, q) {
      let l = ONE, r = ONE;
      for (let k = 0; k < p; k++) l = this.left(k, l, wins[this.order[k]]);
      for (let k = this.order.length - 1; k > q; k--) r = this.right(k, r, wins[this.order[k]]);
      return [l, r];
    }

    /* (n, r1) matrix: l (r0) times the core at every node */
    rows(k, l) {
      const [r0, n, r1] = this.shapes[k], core = this.cores[k], out = new Float64Array(n * r1);
      for (let a = 0; a < r0; a++) {
        const la = l[a];
        if (la === 0) continue;
        for (let node = 0; node < n; node++) {
          const base = (a * n + node) * r1, o = node * r1;
          for (let b = 0; b < r1; b++) out[o + b] += la * core[base + b];
        }
      }
      return out;
    }

    nodal1(wins, j) {
      const p = this.position.get(j), [l, r] = this.ends(wins, p, p);
      const [, n, r1] = this.shapes[p], rows = this.rows(p, l), out = new Float64Array(n);
      for (let node = 0; node < n; node++) {
        let s = 0;
        for (let b = 0; b < r1; b++) s += rows[node * r1 + b] * r[b];
        out[node] = s;
      }
      return out;
    }

    nodal2(wins, j, k) {
      let p = this.position.get(j), q = this.position.get(k), swap = false;
      if (p > q) { [p, q] = [q, p]; swap = true; }
      const [l, r] = this.ends(wins, p, q);
      const np = this.shapes[p][1];
      // rows of core p, then the fixed cores between p and q applied to each
      let width = this.shapes[p][2], block = this.rows(p, l);
      for (let c = p + 1; c < q; c++) {
        const next = new Float64Array(np * this.shapes[c][2]);
        for (let a = 0; a < np; a++) {
          const v = this.left(c, block.subarray(a * width, (a + 1) * width), wins[this.order[c]]);
          next.set(v, a * v.length);
        }
        width = this.shapes[c][2];
        block = next;
      }
      const [r0, nq, r1] = this.shapes[q], core = this.cores[q];
      const right = new Float64Array(r0 * nq);  // core q times r: (r0, nq)
      for (let a = 0; a < r0; a++) {
        for (let node = 0; node < nq; node++) {
          const base = (a * nq + node) * r1;
          let s = 0;
          for (let b = 0; b < r1; b++) s += core[base + b] * r[b];
          right[a * nq + node] = s;
        }
      }
      const out = new Float64Array(np * nq);
      for (let a = 0; a < np; a++) {
        for (let c = 0; c < r0; c++) {
          const x = block[a * width + c];
          if (x === 0) continue;
          for (let node = 0; node < nq; node++) out[a * nq + node] += x * right[c * nq + node];
        }
      }
      if (!swap) return out;
      const t = new Float64Array(np * nq);
      for (let a = 0; a < np; a++) for (let b = 0; b < nq; b++) t[b * np + a] = out[a * nq + b];
      return t;
    }
  }

  class Codebook {
    constructor(layout) {
      this.name = layout.name;
      this.coordinates = layout.coordinates.map((c) => new Coordinate(c));
      this.fields = layout.unknowns.map((u) => {
        if (u.representation === "cp") return new CPField(u);
        if (u.representation === "tt") return new TTField(u);
        throw new Error("unknown representation " + JSON.stringify(u.representation) + " of " + u.name);
      });
      this.unknowns = this.fields.map((f) => f.name);
    }

    windows(xs) {
      return this.coordinates.map((c, j) => c.window(c.clamp(xs[j])));
    }

    /* every unknown at one point (values in codebook order) */
    point(xs) {
      const wins = this.windows(xs);
      return this.fields.map((f) => f.point(wins));
    }

    /* every unknown along coordinate j at the samples, the other coordinates at xs */
    curves(xs, j, samples) {
      const wins = this.windows(xs), c = this.coordinates[j];
      return this.fields.map((f) => c.interpolate(f.nodal1(wins, j), samples));
    }

    /* one unknown on the grid samplesJ x samplesK (row-major, J slowest) */
    map(field, xs, j, k, samplesJ, samplesK) {
      const wins = this.windows(xs), f = this.fields[field];
      const cj = this.coordinates[j], ck = this.coordinates[k];
      const nodal = f.nodal2(wins, j, k), nj = cj.n, nk = ck.n, pk = samplesK.length, pj = samplesJ.length;
      const winJ = cj.windowsOf(samplesJ), winK = ck.windowsOf(samplesK);
      const width = (wins) => wins.reduce((s, w) => s + w.w.length, 0);
      const out = new Float64Array(pj * pk);
      // interpolate along the coordinate whose windows cost less over all the other's nodes first
      if (nj * width(winK) + pk * width(winJ) <= nk * width(winJ) + pj * width(winK)) {
        const half = new Float64Array(nj * pk);  // (nodes j, samples k)
        for (let a = 0; a < nj; a++) {
          for (let b = 0; b < pk; b++) {
            const w = winK[b].w, lo = winK[b].lo;
            let s = 0;
            for (let i = 0; i < w.length; i++) s += w[i] * nodal[a * nk + lo + i];
            half[a * pk + b] = s;
          }
        }
        for (let p = 0; p < pj; p++) {
          const w = winJ[p].w, lo = winJ[p].lo;
          for (let i = 0; i < w.length; i++) {
            const wi = w[i], base = (lo + i) * pk;
            for (let b = 0; b < pk; b++) out[p * pk + b] += wi * half[base + b];
          }
        }
        return out;
      }
      const half = new Float64Array(pj * nk);  // (samples j, nodes k)
      for (let p = 0; p < pj; p++) {
        const w = winJ[p].w, lo = winJ[p].lo;
        for (let i = 0; i < w.length; i++) {
          const wi = w[i], base = (lo + i) * nk;
          for (let b = 0; b < nk; b++) half[p * nk + b] += wi * nodal[base + b];
        }
      }
      for (let p = 0; p < pj; p++) {
        for (let b = 0; b < pk; b++) {
          const w = winK[b].w, lo = winK[b].lo;
          let s = 0;
          for (let i = 0; i < w.length; i++) s += w[i] * half[p * nk + lo + i];
          out[p * pk + b] = s;
        }
      }
      return out;
    }
  }

  return {Codebook: Codebook, Coordinate: Coordinate};
})();
