"""The ``afmsim`` command line: a thin layer over the public Python API.

Every command's work is one function call away (named in its help). Bad input exits with code 2
and a one-line message naming the field; nothing is written then.
"""

from __future__ import annotations

from pathlib import Path
from typing import Literal, Optional

import typer
from typer.core import TyperCommand, TyperGroup

from afmsim.stage import HYSTERESIS_MODELS

_Hysteresis = Literal[tuple(HYSTERESIS_MODELS)]  # every plant family, listed in --help


class _FlagsTakeNoValue:
    """On/off flags (``--quiet``, ``--help``) show no ``<bool>`` value in --help: they take none."""

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        for param in self.params:
            if getattr(param, "is_flag", False):
                param.metavar = ""

    def get_help_option(self, ctx):
        option = super().get_help_option(ctx)
        if option is not None:
            option.metavar = ""
        return option


class _Command(_FlagsTakeNoValue, TyperCommand):
    """Every afmsim command."""


class _Group(_FlagsTakeNoValue, TyperGroup):
    """The ``afmsim`` group itself (its --help)."""


class _App(typer.Typer):
    """A Typer app whose commands are :class:`_Command` unless they ask for another class."""

    def command(self, *args, cls=_Command, **kwargs):
        return super().command(*args, cls=cls, **kwargs)


app = _App(cls=_Group, add_completion=False, no_args_is_help=True, pretty_exceptions_enable=False,
           help="afmsim — a virtual atomic-force microscope with hysteretic piezo stages.")


@app.callback()
def _root() -> None:
    """afmsim — a virtual atomic-force microscope with hysteretic piezo stages."""


def _fail(message: str) -> None:
    typer.echo(f"error: {message}", err=True)
    raise typer.Exit(code=2)


@app.command()
def identify(
    out: Optional[Path] = typer.Option(None, help="Run folder to create (default: outputs/identify-default-<time>)."),
    seed: int = typer.Option(0, min=0, help="Seed of the numpy Generator for all noise draws."),
    experiments: int = typer.Option(10, min=1, max=1000, help="Repeated evaluation experiments (fresh noise)."),
    n_operators: int = typer.Option(10, min=1, max=50, help="Backlash operators N per model."),
    hysteresis: Literal[(*HYSTERESIS_MODELS, "all")] = typer.Option(
        "preisach", help="Plant hysteresis family (afmsim.stage.HYSTERESIS_MODELS): preisach (state-bound minor "
        "loops), duhem (direction-bound) or linear; all: every law with hysteresis, same seed, Table 2 side by side "
        "(each law's own outputs in <out>/<law>/)."),
):
    """Identify SPI, DIAPI, IIAPI and the better model on the default stage (paper §3.2, Tables 1–2).

    Python: afmsim.identification.identify(...) and write_identification(...); --hysteresis all: identify_laws(...) and write_identification_laws(...).
    """
    from afmsim.identification import identify as run_identify, table1, table2, write_identification
    from afmsim.runio import default_run_dir, run_folder
    from afmsim.stage import default_stage

    out = out or default_run_dir("identify", hysteresis)
    config = {"seed": seed, "experiments": experiments, "n_operators": n_operators, "hysteresis": hysteresis}
    if hysteresis == "all":
        from afmsim.identification import identify_laws, table2_laws, write_identification_laws
    try:
        with run_folder(out, config=config, seed=seed, command="identify") as folder:
            if hysteresis == "all":
                results = identify_laws(seed=seed, experiments=experiments, n_operators=n_operators)
                write_identification_laws(results, folder)
            else:
                result = run_identify(default_stage(hysteresis), seed=seed, experiments=experiments,
                                      n_operators=n_operators)
                write_identification(result, folder)
    except FileExistsError as error:
        _fail(str(error))
    if hysteresis == "all":
        typer.echo(table2_laws(results))
        typer.echo(f"\nTable 1 of each law: {out}/<law>/tables.txt ({', '.join(results)})")
        typer.echo(f"wrote {out}")
        return
    typer.echo(table1(result))
    typer.echo("")
    typer.echo(table2(result))
    typer.echo(f"\nwrote {out}")


def _load(scenario_path: Path):
    from afmsim.scenario import ScenarioError, load_scenario

    try:
        return load_scenario(scenario_path)
    except ScenarioError as error:
        _fail(str(error))


def _preflight(loaded):
    """(needed, available) bytes, or exit 2 if the sample file is unreadable or the run would not fit."""
    from afmsim.resources import preflight
    from afmsim.scenario import ScenarioError

    try:
        return preflight(loaded)
    except ScenarioError as error:
        _fail(str(error))


@app.command()
def validate(scenario: Path = typer.Argument(..., help="Scenario or sweep YAML file.")):
    """Check a scenario or a sweep file without running it: fields, sample file, memory estimate
    (for a sweep: every run it expands to).

    Python: afmsim.scenario.load_scenario(path), then afmsim.resources.preflight(scenario); a sweep
    file (one with a ``base``): afmsim.sweep.load_sweep(path), then preflight(run.scenario) per run.
    """
    from afmsim.resources import format_bytes
    from afmsim.scenario import ScenarioError, read_yaml
    from afmsim.sweep import SweepError, parse_sweep

    try:
        data = read_yaml(scenario)
    except ScenarioError as error:
        _fail(str(error))
    if not (isinstance(data, dict) and "base" in data):  # a scenario has no 'base'; a sweep file must
        loaded = _load(scenario)
        needed, available = _preflight(loaded)
        what = f"{loaded.experiments} experiments, controllers: {', '.join(loaded.controllers)}; needs"
    else:
        try:
            sweep = parse_sweep(data, scenario.parent)
        except SweepError as error:
            _fail(str(error))
        checked = [_preflight(run.scenario) for run in sweep.runs()]
        needed, available = max(n for n, _ in checked), checked[-1][1]
        what = (f"sweep of {len(checked)} runs varying {', '.join(sweep.parameters)} on {sweep.base.name}; "
                f"the largest run needs")
    free = f"{format_bytes(available)} available" if available is not None else "available memory unknown"
    typer.echo(f"{scenario}: valid ({what} ≈ {format_bytes(needed)} of memory, {free})")


@app.command()
def run(
    scenario: Path = typer.Argument(..., help="Scenario YAML file."),
    out: Optional[Path] = typer.Option(None, help="Run folder to create (default: outputs/run-<name>-<time>)."),
    experiments: Optional[int] = typer.Option(None, min=1, max=1000, help="Override the scenario's experiment count."),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="No progress bar."),
    renders: str = typer.Option("key", help="3D renders: none, key (the sample, the uncompensated and the best "
                                "controller) or all (trace and retrace of every controller)."),
    workers: Optional[int] = typer.Option(None, min=1, max=256, help="Worker processes for scans and figures "
                                          "(default: every core; results are the same bits for any count)."),
):
    """Run a scenario: scans per controller, images, metrics (paper Tables 3–4).

    Python: afmsim.resources.preflight(scenario), afmsim.experiment.run_scenario(scenario, workers=N) and
    afmsim.report.run_output.write_run(result, folder, renders="key").
    """
    import sys
    import time

    from afmsim.experiment import run_scenario
    from afmsim.report.render_process import RenderProcess
    from afmsim.report.run_output import write_run
    from afmsim.resources import format_bytes
    from afmsim.runio import default_run_dir, run_folder
    from afmsim.scenario import ScenarioError, parse_scenario

    started = time.perf_counter()
    from afmsim.report.run_output import RENDER_CHOICES
    from afmsim.workers import WorkerDied, available_cores

    if renders not in RENDER_CHOICES:
        _fail(f"--renders must be one of {', '.join(RENDER_CHOICES)}, got {renders!r}")
    workers = workers or available_cores()
    loaded = _load(scenario)
    if experiments is not None:
        try:
            loaded = parse_scenario({**loaded.model_dump(mode="json"), "experiments": experiments})
        except ScenarioError as error:
            _fail(str(error))
    needed, _ = _preflight(loaded)
    out = out or default_run_dir("run", loaded.name)
    if out.exists():
        _fail(f"output folder {out} already exists: choose another --out or remove it")
    show = not quiet and sys.stderr.isatty()
    # the 3D renders' start-up (VTK, GL context, shaders) is paid while the run simulates
    render_process = RenderProcess() if renders != "none" else None
    with _progress(show) as progress:
        try:
            extra = {}
            with run_folder(out, config=loaded.model_dump(mode="json"), seed=loaded.seed, command="run",
                            extra=extra) as folder:
                result = run_scenario(loaded, progress=progress, workers=workers)
                simulated = time.perf_counter()
                write_run(result, folder, renders=renders, progress=progress, workers=workers,
                          render_process=render_process)
                extra["timings"] = {**result.timings, "report_s": time.perf_counter() - simulated,
                                    "total_s": time.perf_counter() - started}
        except ValueError as error:
            _fail(str(error).splitlines()[0])
        except OSError as error:
            _fail(f"{error.filename or out}: {error.strerror or error}")
        except MemoryError:
            _fail(f"out of memory (estimated ≈ {format_bytes(needed)}): reduce scan.pixels/lines or "
                  f"numerics.samples_per_pixel")
        except WorkerDied as error:
            _fail(str(error))
        finally:
            if render_process is not None:
                render_process.close()  # a no-op once it has drawn
    _print_summary(result.metrics())
    typer.echo(f"wrote {out}")


@app.command()
def render(
    run_dir: Path = typer.Argument(..., help="A run folder written by 'afmsim run'."),
    interactive: bool = typer.Option(False, "--interactive", help="Open each view in a window (needs a display)."),
):
    """Re-render the 3D views (render_*.png) of a written run from its images.npz and scenario.yaml.

    Python: afmsim.report.renders.load_run_arrays(run_dir) and render_run_views(...).
    """
    from afmsim.report.renders import load_run_arrays, rebuild_mesh, render_run_views
    from afmsim.scenario import ScenarioError

    try:
        scenario, images, truth = load_run_arrays(run_dir)
    except (OSError, ValueError, ScenarioError) as error:
        _fail(str(error).splitlines()[0])
    from afmsim.render import RenderingUnavailable

    try:
        written, warning = render_run_views(images, truth, rebuild_mesh(scenario), run_dir, name=scenario.name,
                                            interactive=interactive)
    except RenderingUnavailable as error:
        _fail(str(error).splitlines()[0])
    if warning:
        _fail(warning)
    typer.echo(f"wrote {len(written)} renders into {run_dir}")


def _progress(show: bool):
    """A context manager yielding ``progress(stage, done, total)``: a rich bar per stage (identify,
    scan, metrics, figures, renders, report) on a terminal, else silent."""
    from contextlib import contextmanager, nullcontext

    if not show:
        return nullcontext(None)

    @contextmanager
    def bar():
        from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

        # no refresh thread: the run forks worker and render processes, and a fork must not copy a
        # console lock that a refresh thread holds; the bar is redrawn at each update instead
        with Progress(TextColumn("{task.description:>8}"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(),
                      transient=True, auto_refresh=False) as prog:
            tasks = {}

            def update(stage, done, total):
                if stage not in tasks:
                    tasks[stage] = prog.add_task(stage, total=total)
                prog.update(tasks[stage], completed=done, total=total, refresh=True)
            yield update
    return bar()


def _print_summary(metrics: dict) -> None:
    typer.echo(f"{'controller':>10} {'NSL2 mean':>12} {'σ':>10} {'shift x (µm)':>13} {'saturated':>10}")
    for name, scores in metrics["controllers"].items():
        saturated = scores.get("saturated_fraction", {}).get("mean", 0.0)
        typer.echo(f"{name:>10} {scores['nsl2']['mean']:>12.1f} {scores['nsl2']['std']:>10.1f} "
                   f"{scores['shift_x_m']['mean'] * 1e6:>13.3f} {saturated:>10.2%}")
    if "e_D" in metrics:
        typer.echo(f"e_D (SPI → DIAPI, eq. 9): {metrics['e_D']:.1%}")
    for note in metrics.get("notes", []):
        typer.echo(f"note: {note}")


@app.command()
def diagnose(
    measured: Path = typer.Option(..., "--measured", help="Measured data: a loop record CSV (t_s,v_V,x_m[,y_m]), or "
                                                          "trace/retrace images: .npz (trace, retrace, scan_size_m, "
                                                          "line_rate_hz; or a run's images.npz or folder), .gwy, or an "
                                                          "instrument file (.nid, .ibw, .spm, .000-.999, .sxm, .jpk, "
                                                          "Park .tiff: the topography's forward/backward scans, scan "
                                                          "size and line time from the file)."),
    retrace: Optional[Path] = typer.Option(None, "--retrace", help="Images: a second instrument file with the other "
                                                                   "scan direction, for instruments that write one "
                                                                   "direction per file (Park .tiff)."),
    scenario: Optional[Path] = typer.Option(None, "--scenario", help="Scenario YAML of the model: effects its stage "
                                                                     "switches on are already modelled; for images "
                                                                     "also the imaged sample, tip and Z loop."),
    out: Optional[Path] = typer.Option(None, help="Run folder to create (default: outputs/diagnose-<file>-<time>)."),
    baseline: Literal["preisach", "symmetric"] = typer.Option("preisach", help="Baseline hysteresis: preisach "
                                                                                "(asymmetric) or symmetric."),
    reference: Literal["auto", "scenario", "trace"] = typer.Option("auto", help="Images: what the tip traced — scenario (its sample and tip), "
                                               "trace (the measured trace) or auto (scenario when given)."),
    channel: Optional[str] = typer.Option(None, help="Images: controller channel of a run's images.npz/.gwy "
                                                     "(default: none), or the channel of an instrument file "
                                                     "(default: its topography; see 'afmsim inspect')."),
    reverse_lines: bool = typer.Option(False, "--reverse-lines", help="Images: the file stores its lines "
                                                                      "last-scanned first although its format does "
                                                                      "not say so (a .gwy flipped by an import); "
                                                                      "every channel's rows are reversed first."),
    seed: int = typer.Option(0, min=0, help="Recorded for provenance (the diagnosis is deterministic)."),
):
    """Sim-to-real gap diagnosis of measured loops or trace/retrace images: where the baseline misses,
    and which unmodelled effect (creep, drift, dynamics, cross_coupling, asymmetry; for images also
    tip and z_feedback) closes the gap.

    Python: afmsim.diagnosis.diagnose_loops(path, scenario=...) or diagnose_images(path, scenario=...).
    """
    from afmsim.diagnosis import diagnose_images, diagnose_loops, load_images
    from afmsim.readers import reader_for
    from afmsim.runio import default_run_dir, run_folder, write_json

    if measured.is_dir():  # a run folder: its images
        if not (measured / "images.npz").is_file():
            _fail(f"{measured} is a folder without images.npz: give a loop record, an image file or an afmsim run folder")
        measured = measured / "images.npz"
    images = reader_for(measured) is not None
    if retrace is not None and not images:
        _fail(f"--retrace goes with an image file, not with {measured.name}")
    if reverse_lines and not images:
        _fail(f"--reverse-lines goes with an image file, not with {measured.name}")
    loaded = _load(scenario) if scenario is not None else None
    out = out or default_run_dir("diagnose", measured.stem)
    if out.exists():
        _fail(f"output folder {out} already exists: choose another --out or remove it")
    try:  # image files are read (once) and checked, an instrument file's height pair picked, before anything is written
        record = load_images(measured, channel=channel, line_rate_hz=loaded.scan.line_rate_hz if loaded else None,
                             retrace=retrace, reverse_lines=reverse_lines) if images else None
    except ValueError as error:
        _fail(str(error).splitlines()[0])
    picked = record.picked if record is not None else None
    if picked is not None:
        typer.echo(picked)
    config = {"measured": str(measured), **({"retrace": str(retrace)} if retrace is not None else {}),
              "scenario": None if scenario is None else str(scenario), "baseline": baseline,
              "seed": seed, **({"reference": reference, "channel": channel, "reverse_lines": reverse_lines}
                               if images else {}),
              **({"picked": picked} if picked is not None else {})}
    try:
        with run_folder(out, config=config, seed=seed, command="diagnose") as folder:
            if images:
                report, summary = diagnose_images(record, scenario=loaded, reference=reference, channel=channel,
                                                  baseline="asymmetric" if baseline == "preisach" else "symmetric",
                                                  figure_path=folder / "diagnosis.png", rng_seed=seed)
            else:
                report, summary = diagnose_loops(measured, rng_seed=seed, baseline=baseline, scenario=loaded,
                                                 figure_path=folder / "diagnosis.png")
            write_json(folder / "diagnosis.json", report)
            (folder / "summary.txt").write_text(summary + "\n")
    except (ValueError, OSError) as error:
        _fail(str(error).splitlines()[0])
    typer.echo(summary)
    typer.echo(f"wrote {out}")


@app.command()
def inspect(
    file: Path = typer.Argument(..., help="An AFM file: .nid, .gwy, .ibw, .spm, .000-.999, Nanonis .sxm, .jpk, "
                                          "Park .tiff or afmsim's .npz."),
    as_json: bool = typer.Option(False, "--json", help="Print JSON: {format, channels: [{name, direction, quantity, "
                                                       "unit, shape, size_m, line_time_s}], picked}."),
):
    """List every channel of an AFM file: name, direction, quantity, unit, pixels, size, line time,
    and the height pair 'diagnose --measured' would use.

    Python: afmsim.readers.read_afm_file(path), then channel_listing(afm) or format_listing(afm).
    """
    import json

    from afmsim.readers import ReaderError, channel_listing, format_listing, read_afm_file

    try:
        afm = read_afm_file(file)
    except ReaderError as error:
        _fail(str(error))
    typer.echo(json.dumps(channel_listing(afm), indent=2, ensure_ascii=False) if as_json else format_listing(afm))


@app.command("validate-diagnosis")
def validate_diagnosis_command(
    cases: int = typer.Option(30, min=4, max=1000, help="Simulated cases (effects, magnitudes, pairs, nulls)."),
    seed: int = typer.Option(0, min=0, help="Seed of the case generator."),
    kind: Literal["loops", "images"] = typer.Option("loops", help="What is diagnosed: loops (stage records) or "
                                                                  "images (trace/retrace scans)."),
    out: Optional[Path] = typer.Option(None, help="Run folder to create (default: outputs/validate-diagnosis-"
                                                  "<kind>-<time>); the scores go into diagnosis.json, "
                                                  "image_diagnosis.json for images, open_world.json for the "
                                                  "open-world suite."),
    suite: Literal["closed", "open-world"] = typer.Option(
        "closed", help="closed: afmsim's plant, the effects at 10-100x the datasheet (--cases, --seed); open-world: "
                       "four hysteresis families, datasheet and large effects in other forms, nulls and "
                       "non-candidate distractors, 34 cases per seed (--seeds; loops only)."),
    seeds: Optional[str] = typer.Option(None, help="Open-world seeds, comma-separated (default: --seed); "
                                                   "1-6 were the development seeds."),
    workers: Optional[int] = typer.Option(None, min=1, max=1024, help="Worker processes of the loop and "
                                                                      "open-world suites (default: every core)."),
):
    """Prove the diagnosis on simulated data whose effect was withheld from the model.

    Python: afmsim.diagnosis.validate_diagnosis(n_cases, seed, workers=...) or validate_image_diagnosis(n_cases, seed);
    afmsim.diagnosis.loops.open_world.validate_open_world(seeds, workers=...) for --suite open-world.
    The published figures (benchmarks/results/) come from benchmarks/bench_*diagnosis.py and
    benchmarks/bench_open_world.py.
    """
    from afmsim.diagnosis import validate_diagnosis, validate_image_diagnosis
    from afmsim.runio import default_run_dir, run_folder, write_json
    from afmsim.workers import WorkerDied

    open_world = suite == "open-world"
    if open_world and kind != "loops":
        _fail("--suite open-world is for --kind loops only")
    try:
        seed_list = [int(s) for s in seeds.split(",")] if seeds is not None else [seed]
    except ValueError:
        seed_list = []
    if not seed_list or any(s < 0 for s in seed_list):
        _fail(f"--seeds must be comma-separated integers >= 0, got {seeds!r}")
    out = out or default_run_dir("validate-diagnosis", "open-world" if open_world else kind)
    if out.exists():
        _fail(f"output folder {out} already exists: choose another --out or remove it")
    run = validate_diagnosis if kind == "loops" else validate_image_diagnosis
    config = {"suite": suite, "seeds": seed_list, "kind": kind} if open_world else \
        {"cases": cases, "seed": seed, "kind": kind}
    try:
        with run_folder(out, config=config, seed=seed_list[0], command="validate-diagnosis") as folder:
            if open_world:
                from afmsim.diagnosis.loops.open_world import headline, validate_open_world

                result = validate_open_world(seed_list, workers=workers)
                write_json(folder / "open_world.json", result)
                scores = headline(result)
            else:
                scores = run(n_cases=cases, seed=seed, **({"workers": workers} if kind == "loops" else {}))
                write_json(folder / ("diagnosis.json" if kind == "loops" else "image_diagnosis.json"), scores)
    except (ValueError, OSError, WorkerDied) as error:
        _fail(str(error).splitlines()[0])
    summary = {k: v for k, v in scores.items() if not isinstance(v, (list, dict))}
    for key, value in summary.items():
        typer.echo(f"{key}: {value}")
    typer.echo(f"wrote {out}")


@app.command("sweep")
def sweep_command(
    sweep_file: Path = typer.Argument(..., help="Sweep YAML file (base scenario, grid and/or random)."),
    scheduler: Optional[str] = typer.Option(None, help="Address of a running Dask scheduler, e.g. tcp://host:8786 "
                                                       "(default: a local cluster, one worker process per core)."),
    out: Optional[Path] = typer.Option(None, help="Sweep folder (default: outputs/sweep-<name>-<time>)."),
    resume: bool = typer.Option(False, "--resume", help="Continue the sweep in --out: only runs without a checkpoint."),
    workers: Optional[int] = typer.Option(None, min=1, max=1024, help="Worker processes of the local cluster."),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="No progress bar."),
):
    """Run a parameter sweep as Dask tasks: results.csv/.parquet, summary.png, a checkpoint per run.

    Python: afmsim.sweep.run_sweep(afmsim.sweep.load_sweep(path), out_dir, scheduler=..., resume=...).
    """
    import sys

    from afmsim.runio import default_run_dir
    from afmsim.sweep import SweepError, SweepRunError, load_sweep, run_sweep
    from afmsim.sweep.progress import sweep_progress

    try:
        loaded = load_sweep(sweep_file)
    except SweepError as error:
        _fail(str(error))
    if resume and out is None:
        _fail("--resume needs --out: the sweep folder to continue")
    if scheduler is not None and workers is not None:
        _fail("--workers applies to the local cluster only; leave it out with --scheduler")
    out = out or default_run_dir("sweep", loaded.name)
    if out.exists() and not resume:
        _fail(f"output folder {out} already exists: choose another --out, or add --resume to continue it")
    try:
        with sweep_progress(not quiet and sys.stderr.isatty()) as progress:
            table = run_sweep(loaded, out, scheduler=scheduler, resume=resume, progress=progress, workers=workers)
    except SweepError as error:
        _fail(str(error))
    except OSError as error:
        _fail(f"sweep {out}: {str(error).splitlines()[0] if str(error) else type(error).__name__}")
    except SweepRunError as error:
        typer.echo(f"error: {error}", err=True)
        raise typer.Exit(code=1)
    shown = ["run_id", *loaded.parameters, *(c for c in table.columns if c.endswith(".nsl2_mean")), "e_D"]
    typer.echo(table[[c for c in shown if c in table.columns]].to_string(index=False, max_rows=40))
    typer.echo(f"wrote {out} ({len(table)} runs)")


@app.command("calibrate")
def calibrate_command(
    measured: Path = typer.Option(..., "--measured", help="A real AFM file with forward/backward scans (.nid, .gwy, "
                                  ".ibw, .spm, .npz, …) or a loop record CSV (t_s,v_V,x_m[,y_m])."),
    out: Path = typer.Option(..., "--out", help="Folder to create: instrument.yaml, calibration.json, calibration.png."),
    pitch_um: Optional[float] = typer.Option(None, "--pitch-um", help="Known lateral period of the sample, µm."),
    scenario: Optional[Path] = typer.Option(None, "--scenario", help="Scenario whose sample (grating/lenses) gives the period."),
    channel: Optional[str] = typer.Option(None, help="Height channel name (default: the topography/Z channel)."),
    line_time_s: Optional[float] = typer.Option(None, "--line-time-s", help="Time of one scan direction, s (if the file lacks it)."),
    retrace: Optional[Path] = typer.Option(None, "--retrace", help="A second image file with the other scan "
                                                                   "direction (Park .tiff: one direction per file)."),
):
    """Fit a virtual twin of a real AFM from its own trace/retrace images or loop record (issue 12).

    Python: afmsim.twin.calibrate(measured, out, pitch_m=..., scenario=...).
    """
    from afmsim.twin import calibrate

    try:
        report = calibrate(measured, out, pitch_m=None if pitch_um is None else pitch_um * 1e-6, scenario=scenario,
                           channel=channel, line_time_s=line_time_s, retrace=retrace)
    except (ValueError, FileExistsError) as error:
        _fail(str(error))
    except OSError as error:
        _fail(f"{error.filename or out}: {error.strerror or error}")
    held = report["held_out"]
    if "rms_error_m" in held:
        typer.echo(f"held-out lines: shift-profile RMS error {held['rms_error_m'] * 1e6:.3f} µm "
                   f"(measured profile RMS {held['measured_rms_m'] * 1e6:.3f} µm)")
    else:
        typer.echo(f"held-out samples: twin RMS {held['twin_rms_m'] * 1e6:.3f} µm, "
                   f"default stage {held['default_stage_rms_m'] * 1e6:.3f} µm")
    typer.echo(f"wrote {out}/instrument.yaml")


@app.command("predict")
def predict_command(
    instrument: Path = typer.Option(..., "--instrument", help="instrument.yaml written by afmsim calibrate."),
    measured: Path = typer.Option(..., "--measured", help="Another file from the same instrument (image pair or loop CSV)."),
    out: Path = typer.Option(..., "--out", help="Folder to create: prediction.json, prediction.png."),
    channel: Optional[str] = typer.Option(None, help="Height channel name (default: the topography/Z channel)."),
    line_time_s: Optional[float] = typer.Option(None, "--line-time-s", help="Time of one scan direction, s (if the file lacks it)."),
    seed: int = typer.Option(0, min=0, help="Seed of the Z-loop noise."),
    retrace: Optional[Path] = typer.Option(None, "--retrace", help="A second image file with the other scan "
                                                                   "direction (Park .tiff: one direction per file)."),
):
    """Predict another measurement of the instrument on its twin and on afmsim's default stage (issue 12).

    Python: afmsim.twin.predict(instrument, measured, out).
    """
    from afmsim.twin import predict

    try:
        result = predict(instrument, measured, out, channel=channel, line_time_s=line_time_s, seed=seed,
                         retrace=retrace)
    except (ValueError, FileExistsError) as error:
        _fail(str(error))
    except OSError as error:
        _fail(f"{error.filename or out}: {error.strerror or error}")
    if "rms_error_m" in result:
        default = result["default_stage"]
        typer.echo(f"shift profile: measured RMS {result['measured_rms_m'] * 1e6:.3f} µm; twin error "
                   f"{result['rms_error_m'] * 1e6:.3f} µm"
                   + (f", default stage {default['rms_error_m'] * 1e6:.3f} µm" if default["rms_error_m"] else ""))
        typer.echo(f"NSL2: measured {result['nsl2']['measured']:.0f}, twin {result['nsl2']['predicted']:.0f}"
                   + (f", default stage {default['nsl2']['predicted']:.0f}" if default["nsl2"] else "")
                   + f" (height noise {result['height_noise_m'] * 1e9:.3g} nm from {result['height_noise_from']})")
    else:
        typer.echo(f"held-out RMS: twin {result['twin']['held_out_rms_m'] * 1e6:.3f} µm, "
                   f"default stage {result['default_stage']['held_out_rms_m'] * 1e6:.3f} µm")
    typer.echo(f"wrote {out}/prediction.json")


def main() -> None:  # pragma: no cover - console entry point
    app(prog_name="afmsim")


if __name__ == "__main__":  # pragma: no cover
    main()
