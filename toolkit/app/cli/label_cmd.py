"""`toolkit label DATASET --regions REGIONS.csv --out RUN [--trajectory RUN/trajectory.parquet]`"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer

from toolkit.app.cli import app
from toolkit.errors import ToolkitError

if TYPE_CHECKING:
    from toolkit.features.model import Config


@app.command("label", short_help="Learn places from a few scans, find them along a log.")
def label_command(
    dataset: Annotated[Path, typer.Argument(metavar="DATASET", help="dataset directory")],
    out: Annotated[Path, typer.Option("--out", metavar="DIR", help="run directory to write into")],
    regions: Annotated[
        Path | None,
        typer.Option(metavar="CSV", help="training spans: CSV feature,start,end (times inclusive)"),
    ] = None,
    model: Annotated[
        Path | None,
        typer.Option(
            "--model", metavar="JSON", help="apply a saved model.json instead of learning"
        ),
    ] = None,
    trajectory: Annotated[
        Path | None,
        typer.Option(
            metavar="FILE",
            help="poses t,x,y,theta (e.g. RUN/trajectory.parquet from `toolkit map`); "
            "default: the dataset's ground truth, else its odometry",
        ),
    ] = None,
    smoothing: Annotated[
        str | None,
        typer.Option(
            metavar="MODE",
            help="along the trajectory (Eq. 7): forward-backward (the default: the whole log), "
            "forward (streaming: only the scans so far) or none",
        ),
    ] = None,
    robust: Annotated[
        float | None,
        typer.Option(
            metavar="W",
            help="per beam, the weight of the world's model against the feature's "
            "(default 0.9; lower trusts every beam of the taught scans more)",
        ),
    ] = None,
    evidence_length: Annotated[
        float | None,
        typer.Option(
            "--evidence-length",
            metavar="M",
            help="m of path per scan's worth of evidence in the HMM (default 0.5, 0.15 with "
            "--none-model surroundings; 0: every "
            "scan counts fully, as if consecutive scans were independent); when learning "
            "(a --model keeps its own)",
        ),
    ] = None,
    lateral: Annotated[
        str | None,
        typer.Option(
            "--lateral",
            metavar="K|auto",
            help="weight each beam by |sin(bearing)|^K, so that what is beside the robot "
            "decides its place, not what it drives towards; 'auto': K of 0, 1 or 2, whichever "
            "lets each training span, held out, be best predicted by the other spans of its "
            "feature (default 0; auto with --none-model surroundings); when learning",
        ),
    ] = None,
    none_model: Annotated[
        str | None,
        typer.Option(
            "--none-model",
            metavar="MODEL",
            help="expert: the per-beam model instead of the scan descriptors, with 'none' as "
            "world (the whole log's per-beam histogram) or surroundings (each feature's own "
            "model where its reading is common in the log, the world where it is "
            "distinctive; strict returns, 0.15 m of evidence length, --lateral auto); "
            "docs/places.md",
        ),
    ] = None,
    beam_term: Annotated[
        float | None,
        typer.Option(
            "--beam-term",
            metavar="W",
            help="expert: add the per-beam model's log-posterior, times this weight, to the "
            "descriptor classifier's (default 0: left out; see the ablation in "
            "docs/places.md)",
        ),
    ] = None,
    context: Annotated[
        float | None,
        typer.Option(
            "--context",
            metavar="M",
            help="expert: m of path before and after each scan whose descriptors' mean and "
            "spread join its own (default 1; 0: each scan alone); when learning",
        ),
    ] = None,
    classifier: Annotated[
        str | None,
        typer.Option(
            "--classifier",
            metavar="KIND",
            help="expert: trees (the default: extremely randomised trees) or logistic (a "
            "regularised logistic regression with a temperature); when learning",
        ),
    ] = None,
    open_set: Annotated[
        str | None,
        typer.Option(
            "--open-set",
            metavar="MODE",
            help="expert: 'none' learnt from the training log's scans no taught place claims: "
            "auto (the default: when the places claim under 0.3 of the log, taught spots in "
            "an untaught background), always or never; docs/places.md; when learning",
        ),
    ] = None,
    check_places: Annotated[
        str | None,
        typer.Option(
            "--check-places",
            metavar="NAMES",
            help="expert: comma-separated places whose calls must resemble the scans the "
            "trees learnt them from (default door,window: the spots in a corridor, whose "
            "false calls sit at hall ends, corner exits and a window's flanks); name yours if "
            "you call them otherwise; none: no check; docs/places.md; when learning",
        ),
    ] = None,
    paper: Annotated[
        bool,
        typer.Option(
            "--paper", help="the paper's literal per-beam Gaussian model (for comparison)"
        ),
    ] = False,
    truth: Annotated[
        Path | None,
        typer.Option(
            metavar="FILE",
            help="true labels (t, label; e.g. the simulator's truth.parquet) to score",
        ),
    ] = None,
    config_file: Annotated[
        Path | None,
        typer.Option(
            "--config",
            metavar="JSON",
            help="expert: settings of the places' Config, a JSON object of field: value "
            '(e.g. {"room_margin": 0}; a model.json: its "config"), over the defaults (or '
            "--paper's, --none-model's); the options above win; docs/places.md; when learning",
        ),
    ] = None,
    set_: Annotated[
        list[str] | None,
        typer.Option(
            "--set",
            metavar="KEY=VALUE",
            help="expert: a field of the places' Config (toolkit/features/model.py), "
            "repeatable, over --config's; VALUE is JSON (0.4, true, null, "
            '["window", "door"]) or else text; when learning',
        ),
    ] = None,
    force: Annotated[bool, typer.Option("--force", help="replace earlier label outputs")] = False,
) -> None:
    """Learn places from a few scans each and find them along the whole log (Eq. 7-9).

    The default: scan descriptors and their context along the path (docs/places.md),
    extremely randomised trees self-trained on the log, smoothed along the trajectory by
    the HMM, with "none"."""
    # on use: the features (numba, scipy, scikit-learn) load for `label` alone

    from toolkit.errors import ToolkitError
    from toolkit.features.figures import write_figures  # matplotlib and Open3D: label alone
    from toolkit.features.model import NONE_MODELS, PAPER, SMOOTHINGS, SURROUNDINGS, Config
    from toolkit.features.run import label_run

    if none_model is not None and none_model not in NONE_MODELS:
        raise ToolkitError(f"--none-model {none_model!r}: use one of {', '.join(NONE_MODELS)}")
    base = (
        PAPER
        if paper
        else SURROUNDINGS
        if none_model == "surroundings"
        else Config(descriptors=False)
        if none_model == "world"
        else Config()
    )
    if config_file is not None or set_:
        if model is not None:
            raise ToolkitError("--config and --set are learning settings; a --model keeps its own")
        base = config_settings(base, config_file, set_)
    if beam_term is not None:
        if beam_term < 0:
            raise ToolkitError(f"--beam-term {beam_term}: a weight >= 0")
        base = replace(base, beam_term=beam_term)
    if context is not None:
        if context < 0:
            raise ToolkitError(f"--context {context}: a distance >= 0 (m)")
        base = replace(base, context=context)
    if classifier is not None:
        base = replace(base, classifier=classifier)  # type: ignore[arg-type]  # Config checks
    if open_set is not None:
        base = replace(base, open_set=open_set)  # type: ignore[arg-type]  # Config checks
    if check_places is not None:
        names = tuple(n.strip() for n in check_places.split(",") if n.strip())
        base = replace(base, resemble_places=() if names == ("none",) else names)
    config: Config | None = base
    if smoothing is not None:
        if smoothing not in SMOOTHINGS:
            raise ToolkitError(f"--smoothing {smoothing!r}: use one of {', '.join(SMOOTHINGS)}")
        config = replace(base, smoothing=smoothing)  # type: ignore[arg-type]  # checked above
    if robust is not None:
        if not 0.0 <= robust < 1.0:
            raise ToolkitError(f"--robust {robust}: a weight in [0, 1)")
        config = replace(config or base, robust=robust)
    if evidence_length is not None:
        if evidence_length < 0:
            raise ToolkitError(f"--evidence-length {evidence_length}: a distance >= 0 (m)")
        config = replace(config or base, evidence_length=evidence_length or None)
    if lateral is not None:
        config = replace(config or base, lateral_weight=lateral_exponent(lateral))
    if model is not None and smoothing is None:
        config = None  # a saved model keeps its own settings
    for given, flag in (
        (beam_term, "--beam-term"),
        (context, "--context"),
        (classifier, "--classifier"),
        (open_set, "--open-set"),
        (check_places, "--check-places"),
    ):
        if model is not None and given is not None:
            raise ToolkitError(f"{flag} is a learning setting; a --model keeps its own")
    metrics = label_run(
        dataset, out, regions, model, trajectory, config, force, truth, write_figures
    ).metrics
    counts = ", ".join(f"{k} {v}" for k, v in metrics["label_counts"].items())
    typer.echo(f"labelled {metrics['scans']} scans in {metrics['seconds']} s: {counts}")
    if "truth" in metrics:
        t = metrics["truth"]
        typer.echo(
            f"against truth ({t['scored_scans']} scans): balanced accuracy "
            f"{t['balanced_accuracy']:.3f}, ECE {t['ece']:.3f}"
        )
    typer.echo(f"wrote {out}/ (labels.parquet, model.json, membership.png, labels-cloud.ply)")


def config_settings(base: Config, path: Path | None, pairs: list[str] | None) -> Config:
    """`base` with --config's fields, then --set's (a model.json's "config" as a file)."""
    from toolkit.app.settings import apply, parse_sets, read_json

    if path is not None:
        data = read_json(path)
        saved = data.get("config")
        if isinstance(saved, dict) and "features" in data:  # a model.json
            data = saved
        base = apply(base, data, str(path))
    return apply(base, parse_sets(pairs), "--set")


def lateral_exponent(text: str) -> float | None:
    """--lateral: an exponent in [0, 8], or None for 'auto'."""
    if text.strip().lower() == "auto":
        return None
    try:
        value = float(text)
    except ValueError:
        value = float("nan")
    if not 0.0 <= value <= 8.0:
        raise ToolkitError(f"--lateral {text}: an exponent in [0, 8] or auto")
    return value
