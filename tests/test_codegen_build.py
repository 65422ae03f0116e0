"""The compile cache: keyed by what shaped a library, including the CPU when built for it."""

from __future__ import annotations

from pathlib import Path

import pytest

from mpclab.codegen import build

SOURCE = "double twice(double x) { return 2.0 * x; }\n"


def test_a_library_is_keyed_by_source_compiler_and_flags() -> None:
    key = build.source_key(SOURCE, "/usr/bin/gcc", ["-O1"])
    assert key == build.source_key(SOURCE, "/usr/local/bin/gcc", ["-O1"])  # the name counts
    assert key != build.source_key(SOURCE, "/usr/bin/gcc", ["-O2"])
    assert key != build.source_key(SOURCE + " ", "/usr/bin/gcc", ["-O1"])


def test_native_code_is_keyed_by_this_cpu(monkeypatch) -> None:
    assert build.host_key(["-O3"]) == ""
    here = build.host_key(["-O3", "-march=native"])
    assert here  # names this CPU
    key = build.source_key(SOURCE, "gcc", ["-march=native"])
    other = "model name\t: another CPU\nflags\t\t: fpu\n"
    real_read = Path.read_text
    monkeypatch.setattr(Path, "read_text", lambda self, *a, **k: other
                        if str(self) == "/proc/cpuinfo" else real_read(self, *a, **k))
    assert build.host_key(["-march=native"]) != here
    assert build.source_key(SOURCE, "gcc", ["-march=native"]) != key


def test_an_indexed_build_writes_its_source_once(tmp_path, monkeypatch) -> None:
    if build.find_compiler() is None:
        pytest.skip("no C compiler")
    monkeypatch.setenv("MPCLAB_CACHE", str(tmp_path))
    written: list[int] = []

    def source() -> str:
        written.append(1)
        return SOURCE

    a = build.compile_indexed("twice v1", source, "t", ["-O0"])
    b = build.compile_indexed("twice v1", source, "t", ["-O0"])
    assert a == b and a.is_file() and len(written) == 1
    # another key of the same source: written again, the same library found by its source
    assert build.compile_indexed("twice v2", source, "t", ["-O0"]) == a and len(written) == 2


@pytest.mark.skipif(build.find_compiler() is None, reason="needs a C compiler")
def test_a_compile_announces_itself_before_it_starts(tmp_path, monkeypatch, capsys) -> None:
    monkeypatch.setenv("MPCLAB_CACHE", str(tmp_path))
    said_before: list[str] = []
    real_run = build.subprocess.run

    def run(*args, **kwargs):  # the compiler starts: what was said by then
        said_before.append(capsys.readouterr().err)
        return real_run(*args, **kwargs)

    monkeypatch.setattr(build.subprocess, "run", run)
    build.compile_shared(SOURCE, "tiny", ["-O1"])
    assert len(said_before) == 1
    assert "mpclab: compiling tiny" in said_before[0] and "roughly" in said_before[0]
    assert str(tmp_path) in said_before[0]  # where the result is kept
    assert "compiled tiny in" in capsys.readouterr().err
    build.compile_shared(SOURCE, "tiny", ["-O1"])  # cached: nothing to say
    assert capsys.readouterr().err == "" and len(said_before) == 1


@pytest.mark.skipif(build.find_compiler() is None, reason="needs a C compiler")
def test_the_generated_c_is_kept_beside_its_library(tmp_path, monkeypatch) -> None:
    monkeypatch.setenv("MPCLAB_CACHE", str(tmp_path))
    lib = build.compile_shared(SOURCE, "kept", ["-O0"], header="double twice(double x);\n",
                               keep_source=True)
    c, h = build.kept_source(lib)
    assert (c.parent, c.suffix, h.suffix) == (lib.parent, ".c", ".h")
    assert c.read_text() == SOURCE and "twice" in h.read_text()
    c.unlink()  # a library compiled before sources were kept: written on the next use
    assert build.compile_shared(SOURCE, "kept", ["-O0"], keep_source=True) == lib
    assert c.read_text() == SOURCE
    plain = build.compile_shared(SOURCE, "plain", ["-O0"])
    assert build.kept_source(plain) == []  # only when asked (a JIT'ed NLP's C is large)


@pytest.mark.skipif(build.find_compiler() is None, reason="needs a C compiler")
def test_codegen_true_says_where_the_generated_c_is(tmp_path, monkeypatch, capsys) -> None:
    from mpclab.cli.app import cli

    monkeypatch.setenv("MPCLAB_CACHE", str(tmp_path / "cache"))
    assert cli(["+experiment=bicycle_scheduled", "+ci=smoke", "controller.codegen=true",
                f"hydra.run.dir={tmp_path / 'run'}"]) == 0
    out = capsys.readouterr()
    said = out.out + out.err
    line = next(ln for ln in said.splitlines() if "generated C" in ln)
    files = [Path(p.strip(",")) for p in line.split() if p.startswith(str(tmp_path))]
    assert sorted(p.suffix for p in files) == [".c", ".h"], line
    assert all(p.is_file() and p.with_suffix(".so").is_file() for p in files)
    assert "mpc_step" in files[0].read_text() and "python -m mpclab.cli.board" in said


def test_the_board_export_refuses_a_controller_without_board_c(tmp_path, capsys) -> None:
    from mpclab.cli import board

    with pytest.raises(SystemExit) as stop:
        board.main(["--out", str(tmp_path / "board"), "+experiment=car_cvxpy"])
    assert stop.value.code == 2
    err = capsys.readouterr().err
    assert "has no C for a board" in err and "controller=scheduled" in err
    assert not (tmp_path / "board").exists()
