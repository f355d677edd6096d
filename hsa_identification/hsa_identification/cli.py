"""Command-line tools: `hsa_identify` (records → parameter YAML + fit report), `hsa_verify` (records
→ RMSE table + figures), `hsa_workspace` (workspace map figure + data). Usage and file formats:
docs/identification.md.

Every tool exits 0 on success and 2 with a message naming the file or parameter at fault.
"""

from __future__ import annotations

import argparse
import json
import sys
from datetime import datetime
from pathlib import Path

import numpy as np
import yaml

from hsa_bag.bagio import BagError
from hsa_core.analysis import workspace
from hsa_core.jaxsetup import configure_jax
from hsa_core.model.params import CONFIG_DIR, HsaParams, ParameterError, load_params
from hsa_core.sysid import calibration, identification, verification
from hsa_identification.records import load_arrays, load_record

DEFAULT_OUT = Path("out/identification")


def _fail(message: str) -> int:
    """Print an error and return exit code 2."""
    print(f"error: {message}", file=sys.stderr)
    return 2


def _base_file(source: str) -> Path:
    """Path of a parameter set given as "fpu"/"epu" or as a file."""
    packaged = CONFIG_DIR / f"{source}.yaml"
    return packaged if packaged.is_file() and Path(source).name == source else Path(source)


def identify_main(argv: list[str] | None = None) -> int:
    """`hsa_identify CAMPAIGN [--out DIR]`: identify the constants from the campaign's records."""
    configure_jax()
    parser = argparse.ArgumentParser(
        prog="hsa_identify",
        description="Least-squares identification of the elastic "
        "and actuation constants from recorded settled holds (identification.md §4).",
    )
    parser.add_argument(
        "campaign", type=Path, help="campaign YAML: base_params, records [{path, role, payload}]"
    )
    parser.add_argument(
        "--out", type=Path, default=None, help=f"output directory (default {DEFAULT_OUT}/<name>)"
    )
    args = parser.parse_args(argv)
    try:
        spec = yaml.safe_load(args.campaign.read_text())
        base_source = str(spec.get("base_params", "fpu"))
        base = load_params(base_source)
        root = args.campaign.parent
        records = [
            load_record(root / r["path"], r["role"], r.get("payload"), r.get("name"))
            for r in spec["records"]
        ]
        hold = {
            k: float(spec[k]) for k in ("settle", "window", "phi_tol", "max_drift") if k in spec
        }
        samples = identification.settled_samples(base, records, **hold)
        result = identification.identify(base, samples)
    except (OSError, KeyError, TypeError, yaml.YAMLError) as exc:
        return _fail(f"{args.campaign}: unusable campaign file ({exc!r})")
    except (BagError, ParameterError, identification.IdentificationError, ValueError) as exc:
        return _fail(str(exc))
    out = args.out or DEFAULT_OUT / args.campaign.stem
    out.mkdir(parents=True, exist_ok=True)
    header = (
        f"identified by hsa_identify on {datetime.now():%Y-%m-%d %H:%M} from {args.campaign} "
        f"({result.n_samples} settled samples; records {', '.join(r.name for r in records)}); "
        f"based on {base_source}: geometry, masses, damping, phi_max and sigma_a_eq unchanged"
    )
    params_path = identification.write_parameter_file(
        _base_file(base_source),
        out / "identified.yaml",
        identification.parameter_updates(result),
        header,
    )
    report = identification.format_report(result, identification.per_rod_constants(base))
    (out / "report.txt").write_text(report + "\n")
    identification.plot_fit(result, out / "fit.png")
    np.savez(
        out / "samples.npz",
        xi=samples.xi,
        phi=samples.phi,
        payload=samples.payload,
        record=samples.record,
        records=np.asarray(samples.records),
    )
    print(report)
    print(f"\nwrote {params_path}, {out / 'report.txt'}, {out / 'fit.png'}, {out / 'samples.npz'}")
    return 0


def verify_record(
    params: HsaParams, path: Path, calibrate_s: float
) -> tuple[verification.Verification, str]:
    """Replay one record; its rest strains from the first `calibrate_s` s if they are a rest at phi
    = 0."""
    t, chiee, phi, _ = load_arrays(path)
    first = t < calibrate_s
    if calibrate_s <= 0.0:
        return verification.verify(params, t, chiee, phi), "rest strains of the parameter file"
    problem = calibration.rest_problem(t[first], chiee[first], phi[first])
    if problem is not None:
        note = f"rest strains of the parameter file (first {calibrate_s:g} s not a rest: {problem})"
    else:
        cal = calibration.calibrate(params, chiee[first])
        params = params.replace(sigma_a_eq=cal.sigma_a_eq)
        note = (
            f"sigma_a_eq calibrated on the first {calibrate_s:g} s: "
            f"{np.round(cal.sigma_a_eq, 6).tolist()}"
        )
    return verification.verify(params, t, chiee, phi), note


def verify_main(argv: list[str] | None = None) -> int:
    """`hsa_verify RECORD... [--params P] [--out DIR]`: replay recorded phi through the model, RMSE
    and figures."""
    configure_jax()
    parser = argparse.ArgumentParser(
        prog="hsa_verify",
        description="Open-loop replay of recorded phi(t) through the "
        "model (Dopri5, 0.1 ms), compared with the measured EE pose and q.",
    )
    parser.add_argument(
        "records", type=Path, nargs="+", help="bag directories, .mcap or .npz files"
    )
    parser.add_argument(
        "--params", default="fpu", help="parameter set: fpu, epu or a YAML file (default fpu)"
    )
    parser.add_argument(
        "--out", type=Path, default=DEFAULT_OUT / "verification", help="output directory"
    )
    parser.add_argument(
        "--calibrate",
        type=float,
        default=0.5,
        metavar="S",
        help="calibrate sigma_a_eq on the first S s when they are a rest at phi = 0 (0: never)",
    )
    parser.add_argument(
        "--window",
        type=float,
        nargs=2,
        default=None,
        metavar=("T0", "T1"),
        help="time window of the figures [s] (default: the first 4 s after phi first changes, as "
        "the paper's figures)",
    )
    args = parser.parse_args(argv)
    try:
        params = load_params(args.params)
        results, notes = {}, {}
        for path in args.records:
            name = path.stem
            results[name], notes[name] = verify_record(params, path, args.calibrate)
    except (BagError, ParameterError, ValueError, OSError) as exc:
        return _fail(str(exc))
    args.out.mkdir(parents=True, exist_ok=True)
    table = verification.format_table(results)
    text = table + "\n" + "\n".join(f"{name}: {note}" for name, note in notes.items())
    (args.out / "verification.txt").write_text(text + "\n")
    metrics = {
        name: {
            "rmse": r.rmse,
            "nrmse": r.nrmse,
            "max_error": r.max_error,
            "lag_s": r.lag,
            "rmse_lagged": r.rmse_lagged,
        }
        for name, r in results.items()
    }
    (args.out / "metrics.json").write_text(json.dumps(metrics, indent=2))
    for name, result in results.items():
        start = verification.excitation_start(result)
        window = tuple(args.window) if args.window else (start, start + 4.0)
        verification.plot(
            result, args.out / f"{name}.png", window, f"{name}: measured vs simulated"
        )
    print(text)
    print(
        f"\nwrote {args.out / 'verification.txt'}, {args.out / 'metrics.json'} and one figure per "
        "record"
    )
    return 0


def workspace_main(argv: list[str] | None = None) -> int:
    """`hsa_workspace [--params P] [--n N] [--out DIR]`: workspace map figure and data."""
    configure_jax()
    parser = argparse.ArgumentParser(
        prog="hsa_workspace",
        description="Reachable end-effector positions over phi in "
        "[0, phi_max]^2 coloured by mean actuation magnitude, with sample configurations.",
    )
    parser.add_argument(
        "--params", default="fpu", help="parameter set: fpu, epu or a YAML file (default fpu)"
    )
    parser.add_argument(
        "--n", type=int, default=41, help="grid points per phi axis (odd: samples on the grid)"
    )
    parser.add_argument("--out", type=Path, default=Path("out/workspace"), help="output directory")
    args = parser.parse_args(argv)
    if args.n < 3:
        return _fail(f"--n must be >= 3, got {args.n}")
    try:
        params = load_params(args.params)
    except ParameterError as exc:
        return _fail(str(exc))
    wmap = workspace.workspace_map(params, args.n)
    if not np.all(wmap.residual < 1e-6):
        return _fail(
            f"{np.sum(wmap.residual >= 1e-6)} equilibria did not converge; the map would be wrong"
        )
    stem = f"workspace_{params.material}"
    data = wmap.save_npz(args.out / f"{stem}.npz")
    figure = workspace.plot_workspace(params, wmap, args.out / f"{stem}.png")
    xy = wmap.chiee[..., :2].reshape(-1, 2)
    print(
        f"{params.material}: x in [{xy[:, 0].min() * 1e3:.1f}, {xy[:, 0].max() * 1e3:.1f}] mm, "
        f"y in [{xy[:, 1].min() * 1e3:.1f}, {xy[:, 1].max() * 1e3:.1f}] mm over {args.n}x{args.n} "
        "phi"
    )
    print(f"wrote {data} and {figure}")
    return 0
