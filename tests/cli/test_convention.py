"""One CLI convention (issue 24): every command that writes files takes ``-o/--output`` (``--out``
kept as an alias), every command takes ``--json`` and ``-q/--quiet``, ``--jobs`` has one default
(the available CPUs), ``puppet`` takes positionals like the others, and ``completion`` prints a
shell script covering every command."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

from facetex._resources import sample_path
from facetex.cli import iter_commands, main

#: commands whose result is printed, not written
PRINTS_ONLY = {"identity", "metrics", "compare", "completion", "samples", "serve"}


LEAVES = dict(iter_commands())


def test_the_walk_finds_every_command():
    assert {"transfer", "puppet", "persona build", "bench puppet", "batch transfer", "report", "samples",
            "completion"} <= set(LEAVES)


@pytest.mark.parametrize("name", sorted(LEAVES))
def test_every_command_follows_the_convention(name):
    opts = LEAVES[name]._option_string_actions
    assert "-q" in opts and "--quiet" in opts, f"{name}: no -q/--quiet"
    if name != "completion":
        assert "--json" in opts, f"{name}: no --json"
    if name.split()[0] not in PRINTS_ONLY:
        assert "-o" in opts and "--output" in opts and "--out" in opts, f"{name}: no -o/--output/--out"
        assert opts["-o"] is opts["--out"]  # one option, two spellings
    if "--jobs" in opts:
        assert opts["--jobs"].default is None, f"{name}: --jobs defaults to {opts['--jobs'].default}"


def test_no_help_text_shows_a_doubled_percent(capsys):
    for name in LEAVES:
        with pytest.raises(SystemExit):
            main(name.split() + ["--help"])
        out = capsys.readouterr().out
        assert "%%" not in out, name


def test_out_is_an_alias_of_output(tmp_path, capsys):
    face = str(sample_path("frl_004_neutral.jpg"))
    assert main(["landmarks", face, "--out", str(tmp_path / "a.png"), "-q"]) == 0
    assert (tmp_path / "a.png").is_file() and "wrote" not in capsys.readouterr().out  # -q: no success lines


def test_samples_and_persona_average_print_json(tmp_path, capsys):
    assert main(["samples", str(tmp_path / "s"), "--json"]) == 0
    data = json.loads(capsys.readouterr().out)
    assert len(data["outputs"]) >= 6 and all(p.startswith(str(tmp_path)) for p in data["outputs"])


def test_puppet_takes_positionals_or_the_old_options():
    from facetex.cli.cmd_puppet import _merge_positionals
    from facetex.errors import BadInputError

    p = LEAVES["puppet"]
    a = p.parse_args(["d.mp4", "x.persona", "-o", "o.mp4"])
    _merge_positionals(a)
    assert (a.driver, a.puppet) == ("d.mp4", "x.persona")
    b = p.parse_args(["--driver", "d.mp4", "--puppet", "x.persona", "--out", "o.mp4"])
    _merge_positionals(b)
    assert (b.driver, b.puppet, b.output) == ("d.mp4", "x.persona", "o.mp4")
    with pytest.raises(BadInputError, match="no puppet"):
        _merge_positionals(p.parse_args(["d.mp4", "-o", "o.mp4"]))
    with pytest.raises(BadInputError, match="two drivers"):
        _merge_positionals(p.parse_args(["d.mp4", "x.persona", "--driver", "e.mp4", "-o", "o.mp4"]))


@pytest.mark.parametrize("shell", ["bash", "zsh"])
def test_completion_scripts_cover_the_commands(shell):
    r = subprocess.run([sys.executable, "-m", "facetex", "completion", shell], capture_output=True, text=True,
                       timeout=120)
    assert r.returncode == 0, r.stderr
    for word in ("transfer", "persona", "puppet", "--output", "--preset"):
        assert word in r.stdout
    if shell == "bash":
        assert subprocess.run(["bash", "-n"], input=r.stdout, text=True).returncode == 0  # valid syntax


def test_transfer_says_each_step_file_once_and_prints_the_loss_terms(tmp_path, capsys):
    face, other = str(sample_path("frl_004_neutral.jpg")), str(sample_path("frl_005_neutral.jpg"))
    out = tmp_path / "o.png"
    assert main(["transfer", face, other, "-o", str(out), "--size", "128", "--iters", "2,2,2",
                 "--save-every", "3", "--print-every", "3"]) == 0
    cap = capsys.readouterr()
    steps = sorted(p.name for p in tmp_path.glob("o_level*_eval*.png"))
    assert steps and all(cap.out.count(f"wrote {tmp_path / s}") == 1 for s in steps), cap.out
    assert "loss" in cap.err and "structure" in cap.err and "tv" in cap.err  # the terms, not only the total
