"""Bit-identity check of the compiled closed-loop simulator across a refactoring.

Runs every scenario of ``SCENARIOS`` at levels A-D (plus level B with
``temperature_friction`` and ``standby_motor``), each with the effects the
scenario requires (fault cases: the jam, the limiter, ...), with the nominal design and
the embedded actuator, and either saves every output signal to an ``.npz``
file or compares a fresh run against such a file.  ``--compare`` exits 1
when any signal differs in a single bit (or a case is missing or fails), so
a refactoring that must keep behaviour can prove it did.

Run::

    python bench/bit_identity.py --save before.npz     # on the commit before
    python bench/bit_identity.py --compare before.npz  # on the commit after
"""

from __future__ import annotations

import argparse
import sys

import numpy as np

import thsa_control as thsa

LEVELS = ("A", "B", "C", "D")
EXTRA = (("B", ("temperature_friction", "standby_motor")),)


def cases():
    for name in thsa.SCENARIOS:
        for level in LEVELS:
            yield f"{name}/{level}", name, level, ()
        for level, effects in EXTRA:
            yield f"{name}/{level}+{'+'.join(effects)}", name, level, effects


def run_all() -> dict[str, np.ndarray]:
    params = thsa.default_parameters()
    design = thsa.load_design(thsa.nominal_design_path())
    out: dict[str, np.ndarray] = {}
    plants: dict = {}
    for key, name, level, effects in cases():
        scenario = thsa.get_scenario(name)
        need = tuple(effects) + tuple(dict.fromkeys(e for e in scenario.required_effects if e not in effects))
        plant = plants.get((level, need))
        if plant is None:
            plant = plants[(level, need)] = thsa.Simulator(thsa.build_plant(level, need))
        try:
            res = plant.run(scenario, design, params)
        except Exception as exc:  # a case that fails is recorded as such, never skipped silently
            out[f"{key}::ERROR"] = np.array(f"{type(exc).__name__}: {exc}")
            continue
        out[f"{key}::time"] = np.asarray(res.time)
        for sig in res.names:
            out[f"{key}::{sig}"] = np.asarray(res[sig])
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    g = ap.add_mutually_exclusive_group(required=True)
    g.add_argument("--save", metavar="FILE.npz")
    g.add_argument("--compare", metavar="FILE.npz")
    args = ap.parse_args(argv)
    now = run_all()
    if args.save:
        np.savez_compressed(args.save, **now)
        print(f"saved {len(now)} arrays of {sum(1 for _ in cases())} cases to {args.save}")
        return 0
    ref = dict(np.load(args.compare, allow_pickle=False))
    bad = 0
    for key in sorted(set(ref) | set(now)):
        if key not in now or key not in ref:
            print(f"MISSING {key} ({'after' if key not in now else 'before'})")
            bad += 1
            continue
        a, b = ref[key], now[key]
        if a.dtype.kind in "US" or b.dtype.kind in "US":
            same = a.shape == b.shape and bool(np.all(a == b))
        else:
            same = a.shape == b.shape and a.dtype == b.dtype and a.tobytes() == b.tobytes()
        if not same:
            diff = (float(np.max(np.abs(a - b))) if a.shape == b.shape and a.dtype.kind == "f" else float("nan"))
            print(f"DIFFERS {key}: max |delta| = {diff:.3g}")
            bad += 1
    n_err = sum(1 for k in now if k.endswith("::ERROR"))
    print(f"{len(now)} arrays compared, {bad} differ or are missing, {n_err} cases raised (identically)")
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
