"""A codebook file is untrusted input: names, links, storage, sizes and bytes are checked before use.

Crafted files are made the way an attacker would: a Codebook built in Python with hostile names
and written by pgdcli's own writer (so its digests are valid), or a real codebook edited with
h5py (external links and storage, virtual datasets, fill values, compression), or its bytes
flipped. Each is refused with one ``CodebookError`` line, quickly, before its data is read.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import h5py
import numpy as np
import pytest
from click.testing import CliRunner

from pgdcli.cli.main import cli
from pgdcli.codebook import io as codebook_io
from pgdcli.codebook.codebook import Codebook, CPTensor
from pgdcli.codebook.export import ExportError, export
from pgdcli.codebook.export_c import c_string, comment_text
from pgdcli.codebook.file_checks import ARRAY_DIGESTS, CONTENT_DIGEST
from pgdcli.errors import CodebookError

HOSTILE = [
    "x */ __attribute__((constructor)) static void pwn(void) { puts(\"PWNED\"); } /*",
    "y\n#include <stdlib.h>\nint pwned = 1;\n",
    "z\x1b[2J\x1b]0;title\x07",
    "w??/\nint pwned;",
    "../../etc/passwd",
]


def invoke(*args):
    return CliRunner().invoke(cli, [str(a) for a in args])


def assert_refused(result, *needles):
    assert result.exit_code == 2, (result.exit_code, result.stdout, result.stderr)
    lines = result.stderr.splitlines()
    assert len(lines) == 1 and lines[0].startswith("Error: "), result.stderr
    assert "\x1b" not in result.stderr and "Traceback" not in result.stderr
    for needle in needles:
        assert needle in lines[0], (needle, lines[0])
    return lines[0]


def hostile_codebook(cb: Codebook, place: str, name: str) -> Codebook:
    """``cb`` with one name replaced by ``name``: the problem, a coordinate or an unknown."""
    coords, fields = list(cb.coordinates), dict(cb.fields)
    if place == "problem":
        return Codebook(coords, fields, name=name, spec_text=cb.spec_text, report=cb.report)
    if place == "coordinate":
        old = coords[-1]
        coords[-1] = type(old)(name, old.domain, old.nodes, old.discretization, old.role, old.breakpoints)
        return Codebook(coords, fields, name=cb.name, spec_text=cb.spec_text, report=cb.report)
    first = next(iter(fields))
    fields = {(name if u == first else u): fm for u, fm in fields.items()}
    return Codebook(coords, fields, name=cb.name, spec_text=cb.spec_text, report=cb.report)


# ----------------------------------------------------------------------------------------------
# names
# ----------------------------------------------------------------------------------------------
@pytest.mark.parametrize("place", ["problem", "coordinate", "unknown"])
@pytest.mark.parametrize("shipped", ["spring", "coupled"])
def test_hostile_names_are_refused_on_load_and_never_exported(tmp_path, codebook_path, shipped, place):
    cb = Codebook.load(codebook_path(shipped))
    for k, name in enumerate(HOSTILE):
        crafted = hostile_codebook(cb, place, name)
        path = tmp_path / f"{place}{k}.h5"
        path.write_bytes(codebook_io.to_bytes(crafted))  # pgdcli's own writer: the digests are valid
        with pytest.raises(CodebookError, match="corrupt codebook"):
            Codebook.load(path)
        with pytest.raises(ExportError, match="name"):
            export(crafted, "c")
        out = tmp_path / f"out{k}.h"
        for command in (["export", path, "--to", "c", "-o", out], ["info", path],
                        ["query", path] + [f"--{c}=0" for c in cb.coordinate_names]):
            assert_refused(invoke(*command), "corrupt codebook")
        assert not out.exists()


def test_a_report_key_that_is_not_a_name_is_refused(tmp_path, codebook_path):
    cb = Codebook.load(codebook_path("spring"))
    path = tmp_path / "report.h5"
    crafted = Codebook(cb.coordinates, cb.fields, name=cb.name, spec_text=cb.spec_text,
                       report={**cb.report, "k\x1b[2J": 1.0})
    path.write_bytes(codebook_io.to_bytes(crafted))
    with pytest.raises(CodebookError, match="report key"):
        Codebook.load(path)


def test_comment_and_string_escapes_compile_to_nothing_injected(tmp_path):
    cc = shutil.which("cc")
    if cc is None:
        pytest.skip("no C compiler (cc) installed: the escapes are checked by their character sets only")
    texts = HOSTILE + ["*/", "/*", "\\", "\"", "??=", "\u202e evil", "\x00nul", "ok name (1, 2) [a]"]
    lines = ["#include <stdio.h>", "#include <string.h>", "int main(void) {", "    int count = 0;"]
    for text in texts:
        lines += [f"    /* {comment_text(text)} */", f"    // {comment_text(text)}",
                  f"    count += (int)strlen({c_string(text)});"]
    lines += ["    printf(\"%d\\n\", count);", "    return 0;", "}"]
    source = tmp_path / "escapes.c"
    source.write_text("\n".join(lines) + "\n")
    exe = tmp_path / "escapes"
    done = subprocess.run([cc, "-std=c99", "-Wall", "-Werror", "-trigraphs", "-o", str(exe), str(source)],
                          capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    run = subprocess.run([str(exe)], capture_output=True, text=True)
    # every string survives byte for byte (up to a NUL, where C strings end); nothing else ran
    expected = sum(len(t.encode().split(b"\0")[0]) for t in texts)
    assert run.stdout.strip() == str(expected) and "PWNED" not in run.stdout


def test_export_has_index_macros_that_compile(tmp_path, codebook_path):
    cc = shutil.which("cc")
    if cc is None:
        pytest.skip("no C compiler (cc) installed")
    cb = Codebook.load(codebook_path("coupled"))
    (name, text), = export(cb, "c")[0].items()
    (tmp_path / name).write_text(text)
    main = tmp_path / "main.c"
    main.write_text(f"""#include <stdio.h>
#include "{name}"
int main(void) {{
    const char *names[PGD_COUPLED_NCOORDS] = {{PGD_COUPLED_COORDINATE_NAMES}};
    double x[PGD_COUPLED_NCOORDS], u[PGD_COUPLED_NOUT];
    x[PGD_COUPLED_COORD_t] = 0.25; x[PGD_COUPLED_COORD_a] = 0.5; x[PGD_COUPLED_COORD_b] = 0.75;
    x[PGD_COUPLED_COORD_c] = 0.125;
    pgd_coupled_eval(x, u);
    printf("%s %.17g\\n", names[PGD_COUPLED_COORD_c], u[PGD_COUPLED_OUT_u3]);
    return 0;
}}
""")
    exe = tmp_path / "main"
    done = subprocess.run([cc, "-std=c99", "-Wall", "-Wextra", "-Werror", "-O2", "-o", str(exe), str(main)],
                          capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    name_c, value = subprocess.run([str(exe)], capture_output=True, text=True).stdout.split()
    expected = cb(t=0.25, a=0.5, b=0.75, c=0.125)["u3"]
    assert name_c == "c" and abs(float(value) - float(expected)) <= 1e-13 * max(1.0, abs(float(expected)))


def test_numbers_beyond_float32_refuse_the_c_export_not_json(codebook_path):
    cb = Codebook.load(codebook_path("spring"))
    u = next(iter(cb.fields))
    fm = cb.fields[u]
    big = Codebook(cb.coordinates, {**cb.fields, u: CPTensor(fm.weights * 1e300, fm.factors)}, name=cb.name)
    with pytest.raises(ExportError, match="float32"):
        export(big, "c")
    with pytest.raises(ExportError, match="float32"):
        export(big, "glsl")
    assert export(big, "json")[1] > 0


# ----------------------------------------------------------------------------------------------
# a codebook is self-contained
# ----------------------------------------------------------------------------------------------
def _copy(codebook_path, tmp_path, name="spring", target="crafted.h5") -> Path:
    path = tmp_path / target
    path.write_bytes(codebook_path(name).read_bytes())
    return path


def _replace_nodes(f, **create):
    del f["coordinates/k/nodes"]
    f.create_dataset("coordinates/k/nodes", **create)


def _external_storage(tmp_path, target):
    def craft(f):
        _replace_nodes(f, shape=(10,), dtype="f8", external=[(str(target), 0, 80)])
    return craft


CRAFTS = {
    "external link": lambda f, tmp: f.__setitem__("unknowns/x/modes/extra", h5py.ExternalLink("/etc/passwd", "/x")),
    "external link replacing an array": lambda f, tmp: (f.__delitem__("coordinates/k/nodes"),
                                                        f.__setitem__("coordinates/k/nodes",
                                                                      h5py.ExternalLink(str(tmp / "other.h5"), "/n"))),
    "soft link": lambda f, tmp: f.__setitem__("report/alias", h5py.SoftLink("/coordinates/k/nodes")),
    "external storage of /etc/passwd": lambda f, tmp: _external_storage(tmp, "/etc/passwd")(f),
    "external storage of a FIFO": lambda f, tmp: _external_storage(tmp, tmp / "fifo")(f),
}


@pytest.mark.parametrize("kind", sorted(CRAFTS))
def test_links_and_external_storage_are_refused_before_reading(tmp_path, codebook_path, kind):
    os.mkfifo(tmp_path / "fifo")
    with h5py.File(tmp_path / "other.h5", "w") as other:
        other["n"] = np.arange(10.0)
    path = _copy(codebook_path, tmp_path)
    with h5py.File(path, "r+") as f:
        CRAFTS[kind](f, tmp_path)
    started = time.process_time()
    with pytest.raises(CodebookError, match="corrupt codebook"):
        Codebook.load(path)
    assert time.process_time() - started < 1.0
    assert_refused(invoke("export", path, "--to", "json"), "corrupt codebook")


def test_a_virtual_dataset_is_refused(tmp_path, codebook_path):
    with h5py.File(tmp_path / "source.h5", "w") as src:
        src["n"] = np.linspace(0.0, 1.0, 64)
    path = _copy(codebook_path, tmp_path)
    with h5py.File(path, "r+") as f:
        n = f["coordinates/k/nodes"].shape[0]
        layout = h5py.VirtualLayout(shape=(n,), dtype="f8")
        layout[:] = h5py.VirtualSource(str(tmp_path / "source.h5"), "n", shape=(64,))[:n]
        del f["coordinates/k/nodes"]
        f.create_virtual_dataset("coordinates/k/nodes", layout, fillvalue=0.0)
    with pytest.raises(CodebookError, match="virtual dataset"):
        Codebook.load(path)


def test_a_fifo_as_the_codebook_is_refused_without_blocking(tmp_path):
    fifo = tmp_path / "cb.h5"
    os.mkfifo(fifo)
    started = time.process_time()
    with pytest.raises(CodebookError, match="not a regular file"):
        Codebook.load(fifo)
    assert time.process_time() - started < 1.0


# ----------------------------------------------------------------------------------------------
# integrity
# ----------------------------------------------------------------------------------------------
def _data_offsets(path: Path) -> dict[str, tuple[int, int]]:
    """Dataset -> (byte offset in the file, stored bytes) of its one chunk or contiguous block."""
    out = {}
    with h5py.File(path, "r") as f:
        def visit(name, obj):
            if not isinstance(obj, h5py.Dataset) or obj.dtype.kind == "O":
                return
            if obj.chunks is not None:
                info = obj.id.get_chunk_info(0)
                out[name] = (info.byte_offset, info.size)
            elif obj.id.get_offset() is not None:
                out[name] = (obj.id.get_offset(), obj.id.get_storage_size())
        f.visititems(visit)
    return out


@pytest.mark.parametrize("shipped", ["spring", "coupled", "heat1d"])
def test_one_flipped_byte_in_any_dataset_is_detected(tmp_path, codebook_path, shipped):
    original = codebook_path(shipped).read_bytes()
    offsets = _data_offsets(codebook_path(shipped))
    assert any(k.startswith("unknowns/") for k in offsets)
    for name, (offset, size) in offsets.items():
        for at in sorted({offset, offset + size // 2, offset + size - 1}):
            data = bytearray(original)
            data[at] ^= 0x10
            path = tmp_path / "flipped.h5"
            path.write_bytes(bytes(data))
            with pytest.raises(CodebookError, match="corrupted") as info:
                Codebook.load(path)
            assert name in str(info.value), (name, str(info.value))


def test_an_edited_attribute_fails_the_metadata_digest(tmp_path, codebook_path):
    path = _copy(codebook_path, tmp_path)
    with h5py.File(path, "r+") as f:
        f["coordinates/k"].attrs["domain"] = np.array([1.0, 3.0])
    with pytest.raises(CodebookError, match="metadata does not match"):
        Codebook.load(path)


def test_format_1_0_files_still_load_unchecked(tmp_path, codebook_path):
    path = _copy(codebook_path, tmp_path)
    with h5py.File(path, "r+") as f:
        f.attrs["encoding-version"] = "1.0"
        del f.attrs[CONTENT_DIGEST]
        del f.attrs[ARRAY_DIGESTS]
    old, new = Codebook.load(path), Codebook.load(codebook_path("spring"))
    point = {c.name: float(np.mean(c.domain)) for c in new.coordinates}
    assert old(**point)["x"] == new(**point)["x"]
    assert "unchecked" in old.info(path)["integrity"] and "checked" in new.info()["integrity"]


# ----------------------------------------------------------------------------------------------
# bounded reading
# ----------------------------------------------------------------------------------------------
def _huge_fill(f):
    _replace_nodes(f, shape=(2**27,), dtype="f8", chunks=(2**20,))  # 1 GiB declared, nothing stored


def _huge_report_gzip(f):
    f.create_dataset("report/zeros", data=np.zeros(2**24), compression="gzip", chunks=(2**20,))


def _huge_core_fill(f):
    del f["unknowns/x/modes/t"]
    f.create_dataset("unknowns/x/modes/t", shape=(2**14, 2**14), dtype="f8", chunks=(256, 256))


def _huge_attribute(f):
    f["report"].attrs["big"] = np.zeros(5 * 2**17)  # 5 MiB


R1 = {"nodes of 1 GiB as a fill value": _huge_fill, "report zeros compressed by gzip": _huge_report_gzip,
      "modes of 2 GiB as a fill value": _huge_core_fill, "an attribute of 5 MiB": _huge_attribute}


@pytest.mark.parametrize("kind", sorted(R1))
def test_a_small_file_declaring_huge_arrays_is_refused_fast(tmp_path, codebook_path, kind):
    path = _copy(codebook_path, tmp_path)
    with h5py.File(path, "r+") as f:
        R1[kind](f)
    assert path.stat().st_size < 2**23  # megabytes at most, declaring gigabytes
    script = ("import resource, sys\nfrom pgdcli.cli.entry import main\n"
              "try:\n    main(sys.argv[1:])\nfinally:\n"
              "    use = resource.getrusage(resource.RUSAGE_SELF)\n"
              "    sys.stderr.write(f'used {use.ru_utime + use.ru_stime} {use.ru_maxrss}\\n')\n")

    def run(*command):
        done = subprocess.run([sys.executable, "-c", script, *command], capture_output=True, text=True,
                              timeout=120)
        lines = done.stderr.splitlines()
        return done, lines, float(lines[-1].split()[1]), int(lines[-1].split()[2])

    # The resident size of a bare start (Python, numpy, its BLAS buffers) differs from machine to
    # machine; the arrays declared are gigabytes, so what matters is the growth over a valid file's.
    _, _, _, baseline_kib = run("info", str(codebook_path("spring")))
    for command in (["query", str(path), "--t", "0", "--k", "1", "--c", "0"], ["info", str(path)]):
        done, lines, cpu_seconds, rss_kib = run(*command)
        assert done.returncode == 2, done.stderr
        assert len(lines) == 2 and lines[0].startswith("Error: ") and "corrupt codebook" in lines[0], done.stderr
        assert cpu_seconds < 2.0 and rss_kib < baseline_kib + 200 * 1024, (cpu_seconds, rss_kib, baseline_kib)


def test_the_size_limit_has_an_override(tmp_path, codebook_path, monkeypatch):
    path = codebook_path("spring")
    monkeypatch.setenv("PGD_MAX_CODEBOOK_BYTES", str(path.stat().st_size - 1))
    with pytest.raises(CodebookError, match="PGD_MAX_CODEBOOK_BYTES"):
        Codebook.load(path)
    monkeypatch.setenv("PGD_MAX_CODEBOOK_BYTES", "lots")
    assert_refused(invoke("info", path), "PGD_MAX_CODEBOOK_BYTES")


# ----------------------------------------------------------------------------------------------
# atomic writes
# ----------------------------------------------------------------------------------------------
def test_a_full_disk_during_an_export_leaves_the_target_as_it_was(tmp_path, codebook_path, monkeypatch):
    source = codebook_path("coupled")  # written before the disk fills
    target = tmp_path / "out.h"
    target.write_text("previous\n")
    real_write = os.write

    def full(fd, data):
        if len(data) > 4096:
            real_write(fd, bytes(data[:4096]))
            raise OSError(28, "No space left on device")
        return real_write(fd, data)

    monkeypatch.setattr(os, "write", full)
    line = assert_refused(invoke("export", source, "--to", "c", "-o", target),
                          "No space left on device")
    assert str(target) in line
    assert target.read_text() == "previous\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.h"]


def test_an_export_killed_mid_write_leaves_old_or_whole_files(tmp_path, codebook_path):
    source = codebook_path("coupled")
    whole = export(Codebook.load(source), "c")[0]
    text = next(iter(whole.values()))
    target = tmp_path / "out.h"
    target.write_text("previous\n")
    pgd = shutil.which("pgd")
    if pgd is None:
        pytest.skip("pgd console script not on PATH")
    for delay in (0.05, 0.15, 0.3, 0.5, 0.8):
        process = subprocess.Popen([pgd, "export", str(source), "--to", "c", "-o", str(target), "-q"])
        time.sleep(delay)
        process.kill()
        process.wait()
        assert target.read_text() in ("previous\n", text)
        leftovers = [p.name for p in tmp_path.iterdir() if p.name != "out.h"]
        # a killed process cannot clean up: its temporary file is hidden and named for the target
        assert all(n.startswith(".out.h.") and n.endswith(".tmp") for n in leftovers), leftovers


@pytest.fixture
def full_tmpfs(tmp_path):
    """A 512 KiB tmpfs holding a previous codebook and a filler that leaves a few KiB free (root only)."""
    mount = tmp_path / "mnt"
    mount.mkdir()
    done = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=512k", "tmpfs", str(mount)], capture_output=True)
    if done.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here ({done.stderr.decode().strip() or 'not permitted'})")
    try:
        (mount / "cb.h5").write_bytes(b"previous codebook")
        with open(mount / "filler", "wb") as f:
            try:
                f.write(b"\0" * (512 * 1024 - 8192))
            except OSError:
                pass
        yield mount
    finally:
        subprocess.run(["umount", "-l", str(mount)], capture_output=True)


def test_a_solve_onto_a_full_file_system_leaves_the_target_intact(full_tmpfs):
    problem = Path(__file__).resolve().parents[2] / "problems" / "spring.yaml"
    result = invoke("solve", problem, "-o", full_tmpfs / "cb.h5", "-q")
    line = assert_refused(result, "No space left on device")
    assert "cb.h5" in line
    assert (full_tmpfs / "cb.h5").read_bytes() == b"previous codebook"
    assert sorted(p.name for p in full_tmpfs.iterdir()) == ["cb.h5", "filler"]
