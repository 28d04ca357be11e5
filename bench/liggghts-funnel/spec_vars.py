#!/usr/bin/env python3
"""Turns repose's effective angle-of-repose spec (JSON from `repose aor --print-spec`) into the
`-var NAME VALUE` arguments of in.funnel, so that LIGGGHTS runs the same test: grain size,
materials, coefficients, rolling model, time step, insertion region and rate, plate, at-rest
criterion and time cap. Only what in.funnel can reproduce is accepted (funnel protocol,
monodisperse grains); anything else is an error naming the field.

    python3 spec_vars.py spec.json > vars.txt
"""
import json
import math
import sys


INSERT_SEEDS = [49979687, 49979693, 67867967, 67867979, 86028121, 86028157]


def fail(field, reason):
    sys.exit(f"spec_vars.py: {field}: {reason}")


def rayleigh_time(radius, density, youngs, poisson):
    """repose_engine::material::rayleigh_time."""
    shear = youngs / (2.0 * (1.0 + poisson))
    return math.pi * radius * math.sqrt(density / shear) / (0.1631 * poisson + 0.8766)


def main():
    spec = json.load(open(sys.argv[1]))
    if spec["protocol"] != "funnel":
        fail("protocol", f"only the funnel test is scripted, got {spec['protocol']!r}")
    particle = spec["particle"]
    if particle.get("kind") != "fixed":
        fail("particle", f"only fixed-size grains are scripted, got {particle.get('kind')!r}")
    if spec["base"]["material"] != "steel":
        fail("base.material", "only the steel plate is scripted")
    r = particle["radius"]
    d = 2.0 * r
    soil, steel = spec["materials"]["soil"], spec["materials"]["steel"]
    f = spec["funnel"]
    top_diameter = f["outlet_diameter"] + 2.0 * f["cone_height"] / math.tan(
        math.radians(f["wall_inclination_deg"]))
    rim = f["outlet_height"] + f["cone_height"]
    # The factory's region (experiments/src/aor/run.rs, build_rig).
    zmin = rim + 0.5 * d
    zmax = zmin + max(4.0 * d, 0.01)
    half = 0.5 * spec["base"]["size"] + 2.0 * d
    dt = spec["time_step_rayleigh_fraction"] * rayleigh_time(
        r, soil["density"], soil["youngs_modulus"], soil["poisson"])
    g = 9.81
    grain_mass = soil["density"] * math.pi / 6.0 * d ** 3
    fall = math.sqrt(2.0 * zmax / g)
    settle = spec["settle"]
    rolling = spec["rolling_model"]
    if rolling not in ("cdt", "epsd"):
        fail("rolling_model", f"unknown {rolling!r}")
    ss, st = spec["soil_soil"], spec["soil_steel"]
    values = {
        "R": r,
        "D": d,
        "DENS": soil["density"],
        "E_SOIL": soil["youngs_modulus"],
        "NU_SOIL": soil["poisson"],
        "E_STEEL": steel["youngs_modulus"],
        "NU_STEEL": steel["poisson"],
        "E_SS": ss["restitution"],
        "MU_SS": ss["static_friction"],
        "MUR_SS": ss["rolling_friction"],
        "E_ST": st["restitution"],
        "MU_ST": st["static_friction"],
        "MUR_ST": st["rolling_friction"],
        "ROLLING": rolling,
        "ETA_R": spec["epsd_viscous_damping"],
        "DT": dt,
        "SKIN": 0.5 * r,
        "MASS": spec["total_mass"],
        "MASSRATE": spec["mass_rate"],
        "VIN": spec["inlet_speed"],
        "INS_R": 0.35 * top_diameter,
        "INS_ZMIN": zmin,
        "INS_ZMAX": zmax,
        "XY": half,
        "ZLO": -0.02,
        "ZHI": zmax + 0.01,
        "GRAIN_MASS": grain_mass,
        # Insertion is given FILL_FACTOR x the nominal time (the funnel holds the stream back;
        # repose's 2 mm, 0.3 kg pour took 1.6 x), then the fall time.
        "FILL_STEPS": None,
        "NOMINAL_FILL": spec["total_mass"] / spec["mass_rate"] + fall,
        "MIN_STEPS": max(1, round(settle["min_time"] / dt)),
        "CHECK_STEPS": max(1, round(settle["check_interval"] / dt)),
        "KE_THRESHOLD": settle["kinetic_energy_threshold"],
        "CAP_CHECKS": max(1, math.ceil(spec["time_cap"] / settle["check_interval"])),
        # LIGGGHTS wants a prime > 10000; the spec's seed picks one of its suggested primes.
        "SEED": INSERT_SEEDS[int(spec.get("seed", 1)) % len(INSERT_SEEDS)],
    }
    fill_factor = float(sys.argv[2]) if len(sys.argv) > 2 else 2.0
    values["FILL_STEPS"] = math.ceil(
        (fill_factor * spec["total_mass"] / spec["mass_rate"] + fall) / dt)
    if spec.get("damping_law", "exact_restitution") != "edem_formula":
        print("spec_vars.py: note: LIGGGHTS uses EDEM's damping formula; the spec's damping_law "
              f"is {spec.get('damping_law')!r}", file=sys.stderr)
    print(" ".join(f"-var {k} {v}" for k, v in values.items()))


if __name__ == "__main__":
    main()
