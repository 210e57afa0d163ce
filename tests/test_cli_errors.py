"""Bad input to any command: one ``error:`` line (two at most), exit status 2 and nothing on disk, before any work.
Parse errors, typos (with a "did you mean" hint), values a config rejects, output paths that cannot be written,
a run folder another command holds, an .mp4 without ffmpeg; an explicit option under ``--quick``; help pages in plain
text with every option described; Ctrl-C as one line and exit status 130."""

import dataclasses
import io
import json
import os
import pty
import re
import signal
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from experiments import (
    clevr,
    compare,
    generalize,
    hrl,
    instruct,
    kitchen,
    oracle,
    paper,
    patterns,
    records,
    study,
    tsne,
)
from experiments.cli import check_output_path, output_path_problem, parse, plain
from experiments.config import ExperimentConfig, default_config, resolve
from experiments.lock import FolderInUseError, hold, holder
from experiments.recipes import get_recipe
from talar_jax.report import counted
from tests.conftest import TINY_BERT

ROOT = Path(__file__).resolve().parent.parent


def _snapshot(folder: Path) -> dict[str, bytes]:
    """Every file under ``folder`` (relative path -> bytes); empty when it does not exist."""
    if not folder.exists():
        return {}
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


def _error(capsys, main, argv) -> str:
    """Runs a command's ``main`` expecting exit status 2; returns its stderr (one or two lines, the first an
    ``error:`` line, no traceback)."""
    capsys.readouterr()
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    lines = err.splitlines()
    assert 1 <= len(lines) <= 2 and lines[0].startswith("error: ") and "Traceback" not in err, err
    return err


@pytest.fixture
def read_only(monkeypatch):
    """Makes the folders passed to it unwritable for this test: chmod where that binds (not root), else
    ``os.access`` answering no for them (root may write anywhere but a read-only mount)."""
    folders: list[Path] = []

    def make(folder: Path) -> Path:
        folder.mkdir(parents=True, exist_ok=True)
        folders.append(folder.resolve())
        if os.geteuid() != 0:
            folder.chmod(0o555)
        return folder

    real_access = os.access

    def access(path, mode, *args, **kwargs):
        if mode & os.W_OK and Path(path).resolve() in folders:
            return False
        return real_access(path, mode, *args, **kwargs)

    monkeypatch.setattr(os, "access", access)
    yield make
    for folder in folders:
        folder.chmod(0o755)


# --- parse errors --------------------------------------------------------------------------------------------------


def test_a_value_that_does_not_parse_gets_one_line(tmp_path, capsys):
    out = tmp_path / "run"
    err = _error(capsys, clevr.main, ["--seeds", "abc", "--out", str(out)])
    assert err == "error: --seeds: not an integer: 'abc'"
    assert "--ifp.learning-rate: not a number: 'x'" in _error(capsys, kitchen.main, ["--ifp.learning-rate", "x"])
    assert "--seeds: expected one argument" in _error(capsys, clevr.main, ["--out", str(out), "--seeds"])
    assert "unexpected argument: 3" in _error(capsys, clevr.main, ["--quick", "3", "--out", str(out)])
    assert "--predicates: not an integer: 'x'" in _error(capsys, study.main, ["ablation", "--predicates", "x"])
    assert not out.exists()


def test_a_typo_gets_one_line_with_the_hint(tmp_path, capsys):
    out = tmp_path / "run"
    err = _error(capsys, clevr.main, ["--sedes", "2", "--out", str(out)])
    assert err.startswith("error: unrecognized option: --sedes 2") and "did you mean --seeds?" in err
    err = _error(capsys, compare.main, ["--ifp.totl-env-steps", "5", "--out", str(out)])
    assert "did you mean --ifp.total-env-steps" in err
    assert "did you mean --methods?" in _error(capsys, hrl.main, ["--methds", "flat", "--out", str(out)])
    assert not out.exists()


def test_a_study_name_that_is_not_one_gets_one_line(tmp_path, capsys):
    out = tmp_path / "study"
    err = _error(capsys, study.main, ["foo", "--out", str(out)])
    assert "invalid choice: 'foo' (choose from 'ablation', 'dataset-size', 'aligned', 'end-to-end', 'finetuned-b" in err
    assert "arguments are required: NAME" in _error(capsys, study.main, ["--out", str(out)])
    assert not out.exists()


def test_a_value_a_config_rejects_while_parsing_gets_one_line_naming_the_option(tmp_path, capsys):
    out = tmp_path / "run"
    argv = ["--ifp.total-env-steps", "-5", "--out", str(out)]
    assert _error(capsys, clevr.main, argv) == "error: --ifp.total-env-steps must be >= 1, got -5"
    err = _error(capsys, study.main, ["ablation", "--talar.rg-steps", "0"])
    assert err == "error: --talar.rg-steps must be >= 1, got 0"
    argv = ["--ifp.num-envs", "3", "--ifp.minibatch-size", "7", "--out", str(out)]
    assert "error: --ifp: num_envs * rollout_length (192) must be a multiple" in _error(capsys, compare.main, argv)
    assert not out.exists()


def test_argparse_commands_give_one_line_too(tmp_path, capsys):
    assert "invalid choice: 'recrd'" in _error(capsys, records.main, ["recrd"])
    assert "required: dest, --command" in _error(capsys, records.main, ["record", str(tmp_path)])


# --- output paths --------------------------------------------------------------------------------------------------


def test_output_path_problems_are_found_without_creating_anything(tmp_path, read_only):
    file = tmp_path / "file"
    file.write_text("x")
    assert output_path_problem(tmp_path / "new" / "deeper") is None
    assert output_path_problem(file) == f"{file} is a file, not a folder"
    assert output_path_problem(tmp_path, "file") == f"{tmp_path} is a folder, not a file"
    under = file / "sub" / "x.png"
    assert output_path_problem(under, "file") == f"{under} cannot be created: {file} is a file"
    locked = read_only(tmp_path / "locked")
    assert output_path_problem(locked) == f"{locked} is not writable"
    deeper, video = locked / "a" / "b", locked / "v.gif"
    assert output_path_problem(deeper) == f"{deeper} cannot be created: {locked} is not writable"
    assert output_path_problem(video, "file") == f"{video} cannot be created: {locked} is not writable"
    with pytest.raises(ValueError, match="^--json: "):
        check_output_path(locked / "r.json", "--json", "file")
    check_output_path(None, "--json", "file")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["file", "locked"] and not any(locked.iterdir())


def _out_argv(name: str, out: Path) -> tuple:
    """(main, argv) of a command writing its run folder to ``out``."""
    quick = ["--quick", "--encoder", TINY_BERT, "--no-progress"]
    return {
        "clevr": (clevr.main, [*quick, "--out", str(out)]),
        "compare": (compare.main, [*quick, "--methods", "onehot", "--out", str(out)]),
        "patterns": (patterns.main, [*quick, "--out", str(out)]),
        "study": (study.main, ["dataset-size", *quick, "--out", str(out)]),
        "oracle": (oracle.main, ["--quick", "--out", str(out)]),
        "hrl": (hrl.main, ["--quick", "--out", str(out)]),
        "paper": (paper.main, ["--root", str(out)]),
    }[name]


COMMANDS_WITH_OUT = ("clevr", "compare", "patterns", "study", "oracle", "hrl", "paper")


@pytest.mark.parametrize("name", COMMANDS_WITH_OUT)
def test_an_output_folder_that_is_a_file_or_under_one_stops_the_command(name, tmp_path, capsys):
    file = tmp_path / "file"
    file.write_text("keep")
    main, argv = _out_argv(name, file)
    option = "--root" if name == "paper" else "--out"
    assert _error(capsys, main, argv) == f"error: {option}: {file} is a file, not a folder"
    main, argv = _out_argv(name, file / "run")
    assert f"{file / 'run'} cannot be created: {file} is a file" in _error(capsys, main, argv)
    assert _snapshot(tmp_path) == {"file": b"keep"}


@pytest.mark.parametrize("name", ("clevr", "study", "hrl"))
def test_an_output_folder_that_cannot_be_written_stops_the_command(name, tmp_path, capsys, read_only):
    locked = read_only(tmp_path / "locked")
    main, argv = _out_argv(name, locked / "run")
    assert f"{locked / 'run'} cannot be created: {locked} is not writable" in _error(capsys, main, argv)
    assert not any(locked.iterdir())


def test_video_json_and_figure_paths_are_checked_before_anything_loads(tmp_path, capsys, read_only):
    file = tmp_path / "file"
    file.write_text("keep")
    locked = read_only(tmp_path / "locked")
    run = tmp_path / "no-run-here"  # the path checks come first: no run is loaded
    err = _error(capsys, instruct.main, [str(run), "go", "--video", str(locked / "v.gif")])
    assert err == f"error: --video: {locked / 'v.gif'} cannot be created: {locked} is not writable"
    err = _error(capsys, instruct.main, [str(run), "go", "--video", str(file / "v.mp4")])
    assert err == f"error: --video: {file / 'v.mp4'} cannot be created: {file} is a file"
    argv = [str(run), "--instructions", str(file), "--json", str(locked / "r.json")]
    assert "error: --json: " in _error(capsys, generalize.main, argv)
    assert "error: --out: " in _error(capsys, tsne.main, [str(run), "--out", str(file / "fig.png")])
    assert _snapshot(tmp_path) == {"file": b"keep"} and not any(locked.iterdir())


def test_tsne_writes_into_the_first_run_folder_by_default():
    args = tsne.TsneArgs(run_dirs=(Path("runs/compare-clevr"), Path("runs/clevr")), seed=2)
    assert args.figure() == Path("runs/compare-clevr/tsne-seed2.png")  # beside the runs, not the current folder
    assert dataclasses.replace(args, out=Path("x.png")).figure() == Path("x.png")


# --- one command per run folder ------------------------------------------------------------------------------------

HOLDER = textwrap.dedent(
    """
    import sys, time
    from pathlib import Path
    from experiments.lock import hold
    folder = Path(sys.argv[1])
    with hold(folder):
        (folder / "first.txt").write_text("part one\\n")
        print("held", flush=True)
        sys.stdin.readline()  # until the test lets go
        with (folder / "first.txt").open("a") as out:
            out.write("part two\\n")
    """
)


def _start_holder(folder: Path) -> subprocess.Popen:
    """A process that takes the folder's lock as every command does, writes half its output and waits."""
    process = subprocess.Popen(
        [sys.executable, "-c", HOLDER, str(folder)],
        cwd=ROOT,
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        text=True,
    )
    assert process.stdout.readline().strip() == "held"
    return process


def test_a_second_command_on_a_held_folder_stops_at_once_and_the_first_finishes_whole(tmp_path, capsys):
    folder = tmp_path / "run"
    first = _start_holder(folder)
    try:
        before = _snapshot(folder)
        assert holder(folder)["pid"] == first.pid
        err = _error(capsys, clevr.main, ["--quick", "--encoder", TINY_BERT, "--seeds", "1", "--out", str(folder)])
        assert err.startswith(f"error: {folder} is in use by process {first.pid} (") and "\n" not in err
        for name in ("compare", "patterns", "study", "oracle", "hrl", "paper"):
            main, argv = _out_argv(name, folder)
            assert f"{folder} is in use by process {first.pid}" in _error(capsys, main, argv), name
        assert _snapshot(folder) == before  # nothing changed
        with pytest.raises(FolderInUseError, match="in use by process"), hold(folder):
            pass
    finally:
        first.communicate("go\n", timeout=60)
    assert first.returncode == 0
    assert (folder / "first.txt").read_text() == "part one\npart two\n"  # the first's output is whole
    with hold(folder):  # released when the first ended
        assert holder(folder)["pid"] == os.getpid()


def test_the_second_command_as_a_process_prints_one_line_and_exits_2(tmp_path):
    folder = tmp_path / "run"
    first = _start_holder(folder)
    try:
        second = subprocess.run(
            [sys.executable, "-m", "experiments.oracle", "--quick", "--out", str(folder)],
            cwd=ROOT,
            capture_output=True,
            text=True,
            timeout=300,
        )
    finally:
        first.communicate("go\n", timeout=60)
    assert second.returncode == 2, second.stderr
    lines = second.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"error: {folder} is in use by process {first.pid}"), lines
    assert sorted(p.name for p in folder.iterdir()) == [".lock", "first.txt"]


def test_a_killed_holder_leaves_no_stale_lock(tmp_path):
    folder = tmp_path / "run"
    first = _start_holder(folder)
    first.kill()  # SIGKILL: no clean-up runs
    first.wait(timeout=60)
    with hold(folder):
        assert holder(folder)["pid"] == os.getpid()


def test_the_lock_is_reentrant_within_a_process(tmp_path):
    folder = tmp_path / "run"
    with hold(folder), hold(folder / "."), hold(folder):  # compare and study run the pipeline on their own folder
        pass
    probe = "import sys\nfrom experiments.lock import hold\nwith hold(sys.argv[1]):\n    print('took it')\n"
    taken = subprocess.run([sys.executable, "-c", probe, str(folder)], cwd=ROOT, capture_output=True, text=True)
    assert taken.stdout.strip() == "took it", taken.stderr  # released when the outermost hold ended


# --- --quick and explicit options ----------------------------------------------------------------------------------


def test_an_explicit_budget_wins_over_quick():
    parsed = parse(
        ExperimentConfig,
        ["--quick", "--ifp.total-env-steps", "16384", "--talar.rg-steps", "500"],
        default=default_config("clevr"),
    )
    config = resolve(parsed)
    assert config.ifp.total_env_steps == 16_384 and config.talar.rg_steps == 500  # the explicit values
    assert config.ifp.num_envs == 16 and config.talar.translator_steps == 300  # the rest at the quick budget
    assert resolve(config) == config  # commands resolve twice
    plain_quick = resolve(default_config("clevr", quick=True))
    assert plain_quick.ifp.total_env_steps == 10_240 and plain_quick.talar.rg_steps == 300
    recipe = get_recipe("clevr")
    assert recipe.talar.rg_steps != 300 and recipe.ifp.total_env_steps != 10_240


def test_the_oracle_keeps_its_explicit_options_under_quick():
    quick = oracle.oracle_ppo_config(oracle.OracleArgs(quick=True))
    assert (quick.num_envs, quick.rollout_length, quick.total_env_steps) == (16, 32, 10_240)
    given = oracle.oracle_ppo_config(oracle.OracleArgs(quick=True, num_envs=32, total_env_steps=4096))
    assert (given.num_envs, given.rollout_length, given.total_env_steps) == (32, 32, 4096)


# --- help pages ----------------------------------------------------------------------------------------------------

COMMANDS = {
    "clevr": clevr.main,
    "kitchen": kitchen.main,
    "compare": compare.main,
    "patterns": patterns.main,
    "study": study.main,
    "hrl": hrl.main,
    "oracle": oracle.main,
    "paper": paper.main,
    "instruct": instruct.main,
    "generalize": generalize.main,
    "tsne": tsne.main,
}


def _split_help(help_text: str) -> tuple[str, list[str]]:
    """(the opening text, the lines of the argument sections) of an argparse help page."""
    lines = help_text.splitlines()
    first = next(i for i, line in enumerate(lines) if re.match(r"(positional arguments|options):$", line))
    return "\n".join(lines[:first]), lines[first:]


def _undescribed(help_text: str) -> list[str]:
    """Arguments of a help page whose description is only its default (or nothing); ``--help`` itself aside."""
    _, sections = _split_help(help_text)
    entries: list[list[str]] = []
    for line in sections:
        if re.match(r"  \S", line):  # an argument's first line; its description goes on, indented further
            entries.append([line.strip()])
        elif line.startswith("   ") and entries:
            entries[-1].append(line.strip())
    missing = []
    for entry in entries:
        head = re.split(r"\s{2,}", entry[0], maxsplit=1)
        text = " ".join(([head[1]] if len(head) > 1 else []) + entry[1:]).strip()
        if head[0] != "-h, --help" and (not text or text.startswith("(default")):
            missing.append(head[0])
    return missing


def test_the_help_check_finds_an_undescribed_option():
    page = "usage: x\n\noptions:\n  -h, --help  show this\n  --seeds INT  (default: 5)\n  --out PATH  Where.\n"
    assert _undescribed(page) == ["--seeds INT"]


@pytest.mark.parametrize("name", sorted(COMMANDS))
def test_help_pages_are_plain_text_with_every_option_described(name, capsys):
    assert COMMANDS[name](["--help"]) == 0
    text = capsys.readouterr().out
    opening, sections = _split_help(text)
    assert "``" not in text and "Table 2)." not in opening
    assert len(sections) > 5 and _undescribed(text) == [], name


def test_nested_options_keep_the_spelling_the_docs_use():
    config = parse(
        ExperimentConfig,
        ["--talar.no-translator-tokens", "--talar.finetuned-bert-first-layer", "5", "--ifp.total-env-steps", "4096"],
        default=default_config("kitchen"),
    )
    assert config.talar.translator_tokens is False and config.talar.finetuned_bert_first_layer == 5
    assert config.ifp.total_env_steps == 4096 and config.talar.rg_steps == default_config("kitchen").talar.rg_steps
    env_options = parse(
        ExperimentConfig, ["--env-options", "posture_targets", "talar"], default=default_config("kitchen")
    )
    assert env_options.env_options == {"posture_targets": "talar"}
    assert parse(ExperimentConfig, [], default=default_config("clevr")) == default_config("clevr")


def test_the_pipeline_help_says_whose_defaults_it_shows(capsys):
    assert kitchen.main(["--help"]) == 0
    text = capsys.readouterr().out
    assert "The defaults shown are the kitchen recipe's" in text
    assert "defaults: the paper's Table 2" not in text and "N_pn = 4 predicates" not in text


HELP_PROBE = textwrap.dedent(
    """
    import contextlib, importlib, io, json, sys
    from experiments.cli import exit_status
    from talar_jax import runtime
    runtime.configure = runtime.start = lambda *a, **k: None  # a help page needs no JAX set-up
    pages = {}
    for line in sys.argv[1:]:
        module, *words = line.split()
        sys.argv = [module, *words, "--help"]
        printed = io.StringIO()
        with contextlib.redirect_stdout(printed):
            status = exit_status(importlib.import_module(module).main)
        pages[line] = [status, printed.getvalue()]
    print(json.dumps(pages))
    """
)

ARGPARSE_COMMANDS = (
    "experiments.records",
    "experiments.records record",
    "experiments.records restore",
    "experiments.records annotate",
    "experiments.analysis.code_grouping",
    "experiments.analysis.early_curves",
    "experiments.analysis.encoder_neighbours",
    "experiments.analysis.finetuned_bert_drift",
    "experiments.analysis.side_tasks",
    "experiments.analysis.translator_robustness",
    "benchmarks.accelerator",
    "benchmarks.aligned_encoder",
    "benchmarks.bert_reference",
    "benchmarks.env_sps",
    "benchmarks.finetuned_bert",
    "benchmarks.kitchen_model_cost",
    "benchmarks.pipeline",
    "benchmarks.policy_stage",
    "benchmarks.soak",
    "benchmarks.supervised_layouts",
    "benchmarks.train_sps",
)


def test_every_option_of_the_records_analyses_and_benchmarks_is_described():
    probe = subprocess.run(
        [sys.executable, "-c", HELP_PROBE, *ARGPARSE_COMMANDS], cwd=ROOT, capture_output=True, text=True
    )
    assert probe.returncode == 0, probe.stderr
    pages = json.loads(probe.stdout.strip().splitlines()[-1])
    for line, (status, page) in pages.items():
        assert status == 0 and "usage:" in page and _undescribed(page) == [], (line, page)


def test_plain_drops_markup_and_joins_wrapped_lines():
    text = "First ``code`` line\ncontinues (``x``).\n\n    python -m example --flag\n\n- item one\n  goes on\n- two"
    assert plain(text) == "First code line continues (x).\n    python -m example --flag\n- item one goes on\n- two"


def test_counts_are_singular_for_one():
    assert counted(1, "seed") == "1 seed" and counted(5, "seed") == "5 seeds"
    assert counted(12_000, "tuple") == "12,000 tuples"


# --- an .mp4 without ffmpeg ------------------------------------------------------------------------------------------


def test_an_mp4_without_ffmpeg_stops_instruct_before_any_work(tmp_path, capsys, monkeypatch):
    empty = tmp_path / "bin"
    empty.mkdir()
    monkeypatch.setenv("PATH", str(empty))  # no ffmpeg program to find
    run = tmp_path / "no-run-here"  # not loaded: the check comes first
    err = _error(capsys, instruct.main, [str(run), "go", "--video", str(tmp_path / "episode.mp4")])
    assert err.startswith("error: --video ") and "needs the ffmpeg program" in err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bin"]


# --- Ctrl-C ----------------------------------------------------------------------------------------------------------


XLA_LOG_LINE = re.compile(r"[IWEF]\d{4} \d\d:\d\d:\d\d\.\d+ +\d+ \S+:\d+\] ")
"""The prefix of a line XLA logs on stderr itself (absl's format: severity, date, time, thread, file:line)."""


def _interrupt_after(process: subprocess.Popen, sign: bytes, source) -> tuple[int, str]:
    """Reads ``source`` until ``sign`` appears (the command is at work or waiting), sends SIGINT as Ctrl-C does;
    (exit status, stderr)."""
    seen = b""
    while sign not in seen:
        chunk = os.read(source, 4096)
        assert chunk, f"the command ended before {sign!r}: {seen[-2000:]!r}"
        seen += chunk
    process.send_signal(signal.SIGINT)
    _, err = process.communicate(timeout=600)
    # XLA's own C++ log lines (a compilation-cache entry from another CPU, say) are not the command's output
    lines = [line for line in err.decode().splitlines() if not XLA_LOG_LINE.match(line)]
    return process.returncode, "\n".join(lines)


def test_ctrl_c_stops_a_pipeline_command_with_one_line_and_status_130(tmp_path):
    out = tmp_path / "run"
    argv = ["--quick", "--encoder", TINY_BERT, "--no-progress", "--seeds", "1", "--out", str(out)]
    process = subprocess.Popen(
        [sys.executable, "-m", "experiments.clevr", *argv], cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE
    )
    status, err = _interrupt_after(process, b"oracle", process.stdout.fileno())  # the first stage has begun
    assert status == 130 and "Traceback" not in err, err
    assert err.strip().splitlines() == ["stopped (Ctrl-C); run the same command again to resume"], err


def test_interactive_instruct_prompts_and_stops_on_ctrl_c_with_one_line(tmp_path):
    controller, terminal = pty.openpty()  # stdin is a terminal: the session prompts
    process = subprocess.Popen(
        [sys.executable, "-m", "experiments.instruct", "kitchen"],
        cwd=ROOT,
        stdin=terminal,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
    )
    os.close(terminal)
    try:
        status, err = _interrupt_after(process, b"> ", process.stdout.fileno())
    finally:
        os.close(controller)
    assert status == 130 and "Traceback" not in err, err
    assert err.strip().splitlines() == ["stopped (Ctrl-C)"], err


def test_interactive_instruct_prompts_at_a_terminal_and_ends_at_end_of_input(monkeypatch, capsys):
    class Terminal(io.StringIO):
        def isatty(self):
            return True

    monkeypatch.setattr(sys, "stdin", Terminal("Open the microwave\n  \n"))
    assert list(instruct.read_sentences()) == ["Open the microwave", ""]
    assert capsys.readouterr().out == "> > > \n"  # a prompt per line, and the end of input ends the prompt's line
    monkeypatch.setattr(sys, "stdin", io.StringIO("Open the microwave\n"))  # piped: no prompt
    assert list(instruct.read_sentences()) == ["Open the microwave"] and capsys.readouterr().out == ""
