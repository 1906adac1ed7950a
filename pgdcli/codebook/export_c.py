"""C and GLSL sources of a codebook's evaluator (see :mod:`pgdcli.codebook.export` for the layout).

C: one header, C99, libc only (no math.h). Include it in one translation unit::

    #include "pgd_coupled.h"
    double x[PGD_COUPLED_NCOORDS] = {0.25, 0.1, 0.2, 0.3}, u[PGD_COUPLED_NOUT];
    int status = pgd_coupled_eval(x, u);   /* float32: pgd_coupled_eval_f(const float *, float *) */

``status``: 0 inside the domain; bit ``j`` set when coordinate ``j`` was outside its domain and
was clamped to it (the value is then the codebook's at the clamped point); -1 when a
coordinate is NaN (every output is then NaN).

GLSL: ``int pgd_<name>_eval(float coords[D], out float result[M])`` with the same status,
the numbers in one ``const float`` array (GLSL 3.30 / ES 3.00 or later); shader compilers
limit constant arrays, so this suits small codebooks (tens of thousands of numbers).
"""

from __future__ import annotations

import numpy as np

from .. import __version__

__all__ = ["c_header", "glsl_source", "comment_text", "c_string", "FLOAT32_MAX"]

#: Largest finite float32: numbers beyond it have no float32 spelling (the float variant, GLSL).
FLOAT32_MAX = float(np.finfo(np.float32).max)
_SAFE = frozenset("ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789_ .,:;=+-()[]")


def comment_text(text: str, limit: int = 200) -> str:
    """``text`` for a C or GLSL comment: only letters, digits and plain punctuation, on one line.

    Every string from a codebook file reaches a comment through here: anything else (``*/``,
    newlines, backslashes, ``?`` of trigraphs, non-ASCII) becomes ``_``, so the comment cannot end
    early or continue onto the next line, whatever the file holds.
    """
    return "".join(ch if ch in _SAFE else "_" for ch in str(text)[:limit])


def c_string(text: str) -> str:
    """``text`` as a C string literal: printable ASCII kept, everything else as octal escapes."""
    out = []
    for byte in str(text).encode():
        ch = chr(byte)
        out.append(ch if ch in _SAFE else f"\\{byte:03o}")
    return '"' + "".join(out) + '"'


class _Flat:
    """All numbers of a layout in one array, with the offset of each block."""

    def __init__(self, lay: dict):
        self.values: list[float] = []
        self.coords = []
        for c in lay["coordinates"]:
            entry = {"kind": 1 if c["kind"] == "linear" else 0, "n": len(c["nodes"]), "lo": c["domain"][0],
                     "hi": c["domain"][1], "nodes": self.add(c["nodes"])}
            if entry["kind"] == 0:
                entry.update(m=c["slab_size"], slabs=len(c["breakpoints"]) - 1, bp=self.add(c["breakpoints"]),
                             bary=self.add(c["bary"]))
            else:
                entry.update(m=2, slabs=len(c["nodes"]) - 1, bp=0, bary=0)
            self.coords.append(entry)
        self.unknowns = []
        rmax = 1
        for u in lay["unknowns"]:
            if u["representation"] == "cp":
                self.unknowns.append(("cp", u["name"], u["rank"], self.add(u["alphas"]),
                                      [self.add(m) for m in u["modes"]]))
                rmax = max(rmax, u["rank"])
            else:
                cores = [(self.add(core), shape, j) for core, shape, j in zip(u["cores"], u["shapes"], u["mode_order"])]
                self.unknowns.append(("tt", u["name"], cores))
                rmax = max([rmax] + [max(s[0], s[2]) for s in u["shapes"]])
        self.rmax = rmax
        self.mmax = max(c["m"] for c in self.coords)

    def add(self, numbers) -> int:
        offset = len(self.values)
        self.values.extend(float(v) for v in numbers)
        return offset

    def table(self, key: str) -> str:
        return ", ".join(str(c[key]) for c in self.coords)


def _numbers(values, single: bool, per_line: int = 4) -> str:
    if single:
        text = [repr(float(np.float32(v))) + "f" for v in values]
    else:
        text = [repr(float(v)) for v in values]
    return ",\n".join("    " + ", ".join(text[i:i + per_line]) for i in range(0, len(text), per_line))


_C_WEIGHTS = """
/* cardinal weights of x (clamped) for coordinate j: count written from *first on */
static inline int P_weights{S}(int j, T x, T *w, int *first)
{{
    const T *nodes = P_data{S} + P_node_off[j];
    int n = P_n[j], k, lo = 0, hi;
    if (P_kind[j] == 1) {{ /* linear elements: the element whose left node is the last <= x */
        T theta;
        hi = n;
        while (lo < hi) {{ int mid = (lo + hi) / 2; if (nodes[mid] <= x) lo = mid + 1; else hi = mid; }}
        k = lo - 1 < 0 ? 0 : (lo - 1 > n - 2 ? n - 2 : lo - 1);
        theta = (x - nodes[k]) / (nodes[k + 1] - nodes[k]);
        w[0] = (T)1 - theta;
        w[1] = theta;
        *first = k;
        return 2;
    }} else {{ /* Chebyshev slabs: barycentric on the slab of x (a breakpoint belongs to the slab on its right) */
        const T *bp = P_data{S} + P_bp_off[j], *bary = P_data{S} + P_bary_off[j];
        int m = P_m[j], slabs = P_slabs[j], s;
        T sum = 0;
        hi = slabs + 1;
        while (lo < hi) {{ int mid = (lo + hi) / 2; if (bp[mid] <= x) lo = mid + 1; else hi = mid; }}
        s = lo - 1 < 0 ? 0 : (lo - 1 > slabs - 1 ? slabs - 1 : lo - 1);
        *first = s * (m - 1);
        nodes += *first;
        for (k = 0; k < m; ++k) {{
            T d = x - nodes[k];
            if (d == 0) {{ int i; for (i = 0; i < m; ++i) w[i] = (T)(i == k); return m; }}
            w[k] = bary[k] / d;
            sum += w[k];
        }}
        for (k = 0; k < m; ++k) w[k] /= sum;
        return m;
    }}
}}

/* CP: sum_r alpha[r] prod_j (w_j . modes_j[:, r]) */
static inline T P_cp{S}(const T *alpha, const int *mode_off, int rank, T w[][P_MMAX], const int *first,
                       const int *count, T *prod, T *v)
{{
    int j, k, r;
    T total = 0;
    for (r = 0; r < rank; ++r) prod[r] = 1;
    for (j = 0; j < P_NCOORDS; ++j) {{
        for (r = 0; r < rank; ++r) v[r] = 0;
        for (k = 0; k < count[j]; ++k) {{
            const T *row = P_data{S} + mode_off[j] + (first[j] + k) * rank;
            T wk = w[j][k];
            for (r = 0; r < rank; ++r) v[r] += wk * row[r];
        }}
        for (r = 0; r < rank; ++r) prod[r] *= v[r];
    }}
    for (r = 0; r < rank; ++r) total += prod[r] * alpha[r];
    return total;
}}

/* tensor train: next[q] = sum_p sum_k v[p] w[k] core[p, first + k, q] */
static inline void P_core{S}(int off, int r0, int n, int r1, const T *w, int first, int count, const T *v, T *next)
{{
    int p, k, q;
    for (q = 0; q < r1; ++q) next[q] = 0;
    for (p = 0; p < r0; ++p)
        for (k = 0; k < count; ++k) {{
            const T *row = P_data{S} + off + (p * n + first + k) * r1;
            T f = v[p] * w[k];
            for (q = 0; q < r1; ++q) next[q] += f * row[q];
        }}
}}

/* evaluate every unknown at coords[P_NCOORDS] into out[P_NOUT]; status: see the header comment */
static inline int P_eval{S}(const T *coords, T *out)
{{
    T w[P_NCOORDS][P_MMAX], a[P_RMAX], b[P_RMAX];
    int first[P_NCOORDS], count[P_NCOORDS], j, status = 0;
    (void)a; (void)b;
    for (j = 0; j < P_NCOORDS; ++j) {{
        T x = coords[j];
        if (x != x) {{ for (j = 0; j < P_NOUT; ++j) out[j] = x; return -1; }}
        if (x < (T)P_lo[j]) {{ x = (T)P_lo[j]; status |= 1 << j; }}
        else if (x > (T)P_hi[j]) {{ x = (T)P_hi[j]; status |= 1 << j; }}
        count[j] = P_weights{S}(j, x, w[j], &first[j]);
    }}
{BODY}
    return status;
}}
"""


def _c_body(flat: _Flat, prefix: str, suffix: str) -> str:
    lines = []
    for i, u in enumerate(flat.unknowns):
        if u[0] == "cp":
            _, name, rank, alpha, modes = u
            lines.append(f"    {{ /* {comment_text(name)}: CP, rank {rank} */\n"
                         f"        static const int mode_off[P_NCOORDS] = {{{', '.join(map(str, modes))}}};\n"
                         f"        out[{i}] = P_cp{suffix}(P_data{suffix} + {alpha}, mode_off, {rank}, w, first, "
                         f"count, a, b);\n    }}")
        else:
            _, name, cores = u
            lines.append(f"    /* {comment_text(name)}: tensor train, ranks {[s[2] for _, s, _ in cores[:-1]]} */\n"
                         f"    a[0] = 1;")
            for k, (off, (r0, n, r1), j) in enumerate(cores):
                src, dst = ("a", "b") if k % 2 == 0 else ("b", "a")
                lines.append(f"    P_core{suffix}({off}, {r0}, {n}, {r1}, w[{j}], first[{j}], count[{j}], {src}, {dst});")
            lines.append(f"    out[{i}] = {'b' if len(cores) % 2 else 'a'}[0];")
    return "\n".join(lines).replace("P_", prefix + "_")


def _index_macros(upper: str, lay: dict) -> str:
    """``#define <UPPER>_COORD_<name> j`` and ``<UPPER>_OUT_<name> i`` (names are checked identifiers)."""
    lines = [f"#define {upper}_COORD_{c['name']} {j}" for j, c in enumerate(lay["coordinates"])]
    lines += [f"#define {upper}_OUT_{u['name']} {i}" for i, u in enumerate(lay["unknowns"])]
    return "\n".join(lines)


def c_header(lay: dict, ident: str) -> str:
    """The C99 header (see the module docstring)."""
    flat = _Flat(lay)
    prefix, upper = f"pgd_{ident}", f"PGD_{ident.upper()}"
    d, nout = len(flat.coords), len(flat.unknowns)
    coords = "\n".join(f" *   {j}: {comment_text(c['name'])} in [{c['domain'][0]!r}, {c['domain'][1]!r}], "
                       f"{comment_text(c['kind'])}, {len(c['nodes'])} nodes" for j, c in enumerate(lay["coordinates"]))
    outs = "\n".join(f" *   {i}: {comment_text(u['name'])} ({comment_text(u['representation'])})"
                      for i, u in enumerate(lay["unknowns"]))
    head = f"""/* {prefix}.h: evaluator of the pgdcli codebook '{comment_text(lay['name'])}' (generated by pgdcli {__version__}).
 * C99, libc only. int {prefix}_eval(const double *coords, double *out) and
 * int {prefix}_eval_f(const float *coords, float *out) (float32 numbers and arithmetic).
 * Returns 0 inside the domain; bit j set when coordinate j was clamped to its domain; -1 on NaN input.
 * coords[{d}]:
{coords}
 * out[{nout}]:
{outs}
 */
#ifndef {upper}_H
#define {upper}_H

#define {upper}_NCOORDS {d}
#define {upper}_NOUT {nout}
#define {upper}_MMAX {flat.mmax}
#define {upper}_RMAX {flat.rmax}

/* positions in coords[] and out[] by name; the names in order, for an initializer:
 * const char *names[{upper}_NCOORDS] = {{{upper}_COORDINATE_NAMES}}; */
{_index_macros(upper, lay)}
#define {upper}_COORDINATE_NAMES {', '.join(c_string(c['name']) for c in lay['coordinates'])}
#define {upper}_OUTPUT_NAMES {', '.join(c_string(u['name']) for u in lay['unknowns'])}

static const double {prefix}_data[{len(flat.values)}] = {{
{_numbers(flat.values, False)}
}};
static const float {prefix}_data_f[{len(flat.values)}] = {{
{_numbers(flat.values, True)}
}};
static const double {prefix}_lo[{d}] = {{{flat.table('lo')}}};
static const double {prefix}_hi[{d}] = {{{flat.table('hi')}}};
static const int {prefix}_kind[{d}] = {{{flat.table('kind')}}};
static const int {prefix}_n[{d}] = {{{flat.table('n')}}};
static const int {prefix}_m[{d}] = {{{flat.table('m')}}};
static const int {prefix}_slabs[{d}] = {{{flat.table('slabs')}}};
static const int {prefix}_node_off[{d}] = {{{flat.table('nodes')}}};
static const int {prefix}_bp_off[{d}] = {{{flat.table('bp')}}};
static const int {prefix}_bary_off[{d}] = {{{flat.table('bary')}}};
"""
    parts = [head]
    for real, suffix in (("double", ""), ("float", "_f")):
        code = _C_WEIGHTS.format(S=suffix, BODY="@BODY@").replace("@BODY@", _c_body(flat, "P", suffix))
        code = code.replace("P_NCOORDS", f"{upper}_NCOORDS").replace("P_NOUT", f"{upper}_NOUT")
        code = code.replace("P_MMAX", f"{upper}_MMAX").replace("P_RMAX", f"{upper}_RMAX")
        parts.append(code.replace("P_", f"{prefix}_").replace("(T)", f"({real})").replace("T ", f"{real} ")
                     .replace("T *", f"{real} *"))
    parts.append(f"\n#endif /* {upper}_H */\n")
    return "".join(parts)


_GLSL = """
int P_weights(int j, float x, out float w[P_MMAX], out int first)
{
    int n = P_n[j], node = P_node_off[j], lo = 0, hi, k;
    if (P_kind[j] == 1) {
        hi = n;
        while (lo < hi) { int mid = (lo + hi) / 2; if (P_data[node + mid] <= x) lo = mid + 1; else hi = mid; }
        k = clamp(lo - 1, 0, n - 2);
        float theta = (x - P_data[node + k]) / (P_data[node + k + 1] - P_data[node + k]);
        w[0] = 1.0 - theta;
        w[1] = theta;
        first = k;
        return 2;
    }
    int m = P_m[j], slabs = P_slabs[j], bp = P_bp_off[j], bary = P_bary_off[j];
    float sum = 0.0;
    hi = slabs + 1;
    while (lo < hi) { int mid = (lo + hi) / 2; if (P_data[bp + mid] <= x) lo = mid + 1; else hi = mid; }
    first = clamp(lo - 1, 0, slabs - 1) * (m - 1);
    for (k = 0; k < m; ++k) {
        float d = x - P_data[node + first + k];
        if (d == 0.0) { for (int i = 0; i < m; ++i) w[i] = (i == k) ? 1.0 : 0.0; return m; }
        w[k] = P_data[bary + k] / d;
        sum += w[k];
    }
    for (k = 0; k < m; ++k) w[k] /= sum;
    return m;
}

int P_eval(float coords[P_NCOORDS], out float result[P_NOUT])
{
    float w[P_NCOORDS * P_MMAX], row[P_MMAX], a[P_RMAX], b[P_RMAX];
    int first[P_NCOORDS], count[P_NCOORDS], status = 0;
    for (int j = 0; j < P_NCOORDS; ++j) {
        float x = coords[j];
        if (isnan(x)) { for (int i = 0; i < P_NOUT; ++i) result[i] = x; return -1; }
        if (x < P_lo[j] || x > P_hi[j]) { x = clamp(x, P_lo[j], P_hi[j]); status |= 1 << j; }
        count[j] = P_weights(j, x, row, first[j]);
        for (int k = 0; k < P_MMAX; ++k) w[j * P_MMAX + k] = row[k];
    }
BODY
    return status;
}
"""


def _glsl_body(flat: _Flat) -> str:
    lines = []
    for i, u in enumerate(flat.unknowns):
        if u[0] == "cp":
            _, name, rank, alpha, modes = u
            lines.append(f"    /* {comment_text(name)}: CP, rank {rank} */\n"
                         f"    for (int r = 0; r < {rank}; ++r) a[r] = 1.0;")
            for j, off in enumerate(modes):
                lines.append(f"    for (int r = 0; r < {rank}; ++r) b[r] = 0.0;\n"
                             f"    for (int k = 0; k < count[{j}]; ++k)\n"
                             f"        for (int r = 0; r < {rank}; ++r)\n"
                             f"            b[r] += w[{j * flat.mmax} + k] * P_data[{off} + (first[{j}] + k) * {rank} + r];\n"
                             f"    for (int r = 0; r < {rank}; ++r) a[r] *= b[r];")
            lines.append(f"    result[{i}] = 0.0;\n"
                         f"    for (int r = 0; r < {rank}; ++r) result[{i}] += a[r] * P_data[{alpha} + r];")
        else:
            _, name, cores = u
            lines.append(f"    /* {comment_text(name)}: tensor train */\n    a[0] = 1.0;")
            for k, (off, (r0, n, r1), j) in enumerate(cores):
                src, dst = ("a", "b") if k % 2 == 0 else ("b", "a")
                lines.append(f"    for (int q = 0; q < {r1}; ++q) {dst}[q] = 0.0;\n"
                             f"    for (int p = 0; p < {r0}; ++p)\n"
                             f"        for (int k = 0; k < count[{j}]; ++k)\n"
                             f"            for (int q = 0; q < {r1}; ++q)\n"
                             f"                {dst}[q] += {src}[p] * w[{j * flat.mmax} + k] * "
                             f"P_data[{off} + (p * {n} + first[{j}] + k) * {r1} + q];")
            lines.append(f"    result[{i}] = {'b' if len(cores) % 2 else 'a'}[0];")
    return "\n".join(lines)


def glsl_source(lay: dict, ident: str) -> str:
    """GLSL (3.30 / ES 3.00 or later) functions ``pgd_<ident>_eval`` over constant arrays (no #version line)."""
    flat = _Flat(lay)
    prefix, upper = f"pgd_{ident}", f"PGD_{ident.upper()}"
    d, nout = len(flat.coords), len(flat.unknowns)

    def floats(key):
        return ", ".join(repr(float(np.float32(c[key]))) for c in flat.coords)

    head = f"""// {prefix}.glsl: evaluator of the pgdcli codebook '{comment_text(lay['name'])}' (generated by pgdcli {__version__}).
// int {prefix}_eval(float coords[{d}], out float result[{nout}]): 0 inside the domain, bit j set when
// coordinate j was clamped, -1 on NaN. Coordinates: {comment_text(', '.join(c['name'] for c in lay['coordinates']), 2000)};
// results: {comment_text(', '.join(u['name'] for u in lay['unknowns']), 2000)}. Numbers: one const float array ({len(flat.values)}).
#define {upper}_NCOORDS {d}
#define {upper}_NOUT {nout}
#define {upper}_MMAX {flat.mmax}
#define {upper}_RMAX {flat.rmax}
const float {prefix}_data[{len(flat.values)}] = float[{len(flat.values)}](
{_numbers(flat.values, True).replace("f,", ",").rstrip("f")}
);
const float {prefix}_lo[{d}] = float[{d}]({floats('lo')});
const float {prefix}_hi[{d}] = float[{d}]({floats('hi')});
"""
    for key in ("kind", "n", "m", "slabs", "node_off", "bp_off", "bary_off"):
        src = {"node_off": "nodes", "bp_off": "bp", "bary_off": "bary"}.get(key, key)
        head += f"const int {prefix}_{key}[{d}] = int[{d}]({flat.table(src)});\n"
    code = _GLSL.replace("BODY", _glsl_body(flat))
    for macro in ("NCOORDS", "NOUT", "MMAX", "RMAX"):
        code = code.replace(f"P_{macro}", f"{upper}_{macro}")
    return head + code.replace("P_", f"{prefix}_")
