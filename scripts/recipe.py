#!/usr/bin/python3
"""Reads a shipped model's recipe (config/recipes/<model>.yaml) and prints it as
bash assignments for scripts/train_models.sh. Every key is checked: an unknown
or missing one is an error naming the file and the key. With --height-sets
SENSOR.yaml CHANGE_UM it prints the dss --set options of the sensor's design
with its mask CHANGE_UM um higher (as calibrate_height below makes its bags).

Keys:
  sensor            config/sensors/<sensor>.yaml
  set               [KEY=V, ...]: dss generate --set overrides of every bag (optional)
  bags.train        [BAG, ...]; bags.test: BAG; bags.sigma: [BAG, ...], where
                    BAG = {name, count, seed, [offset], [sampling], [anomalies]}
                    and the bag is DATA/<model>.<name>.bag
  train             {arch, epochs, lr, seed, centroid_weighting, feature_corrections,
                    [lattice_phase], [head], [value_saturation], [spot_readout]}: dss train options
  calibrate_sigma   {correction_degree: keep|none|D, symmetry: keep|none|flips|dihedral,
                    [unit_tolerances: K], [spot_bias_degree: D], [nominal_bags: [NAME, ...]]}: K
                    (geometric head) adds
                    the error of a unit built to K x typical tolerances to sigma, for a family model
                    that units are calibrated from; D (geometric head): the spot bias's maximum degree,
                    fitted after the correction (and its change per calibrate_height entry); nominal_bags: the sigma bags without anomalies,
                    on which alone the angle correction, sigma and the spot-mismatch level are
                    fitted (default: all); the others widen the input envelope only
  calibrate_height  {changes_um: [H, ...], count, seed, [noise_free]} (optional, geometric head): per
                    H, COUNT images of the design with its mask H um higher (lower: the cover glass,
                    if thicker, as thick as the mask is high), seeds SEED, SEED + 1, ...; dss
                    calibrate-height fits how the angle correction changes with the height; with
                    noise_free: true the images are rendered without detector noise (the change is
                    the optics', and noise in its fit is error at every unit of that height)
  baseline          centroid (default: dss calibrate on the first training bag), pattern (the
                    whole-pattern estimator of the sensor's design, for masks whose spots merge) or
                    none (a family model: the sensor's own recipe ships its baseline)
  headline          {alpha_mean_deg, beta_mean_deg}: the model's mean error on the test bag,
                    which test/test_shipped_models.cpp pins (not printed)
"""
import os
import shlex
import sys

import yaml


def fail(path, key, why):
    sys.exit("%s: %s: %s" % (path, key, why))


def check(path, where, node, required, optional=()):
    if not isinstance(node, dict):
        fail(path, where, "expected a map")
    for key in node:
        if key not in required and key not in optional:
            fail(path, "%s%s" % (where + "." if where else "", key), "unknown key")
    for key in required:
        if key not in node:
            fail(path, "%s%s" % (where + "." if where else "", key), "missing")


def bag(path, where, node):
    check(path, where, node, ("name", "count", "seed"), ("offset", "sampling", "anomalies"))
    return ":".join(str(node.get(k, d)) for k, d in
                    (("name", ""), ("count", 0), ("seed", 0), ("offset", 0), ("sampling", "random"),
                     ("anomalies", "none")))


def height_sets(sensor_path, change_um, fail_with):
    """The --set overrides of the sensor's design with its mask change_um higher (lower: a cover glass
    thicker than the mask is then high is thinned to it: the mask rests on it)."""
    try:
        with open(sensor_path) as f:
            sensor = yaml.safe_load(f)
        height_mm = float(sensor["mask"]["height_mm"])
        glass = sensor.get("cover_glass") or {}
        thickness_mm = float(glass["thickness_mm"]) if glass.get("enabled") else 0.0
    except (OSError, yaml.YAMLError, KeyError, TypeError, ValueError) as e:
        fail_with("%s: %s" % (sensor_path, e))
    height = height_mm + change_um / 1000.0
    if height <= 0:
        fail_with("a change of %g um leaves no mask height" % change_um)
    sets = ["mask.height_mm=%.6f" % height]
    if thickness_mm > height:
        sets.append("cover_glass.thickness_mm=%.6f" % height)
    return sets


# dss generate --set overrides that render a sensor without detector noise (quantisation stays).
NOISE_FREE_SETS = ["detector_noise.shot_noise=false", "detector_noise.read_noise_e=0",
                   "detector_noise.dark_current_e_per_s=0", "detector_noise.dsnu_fraction=0",
                   "detector_noise.prnu_fraction=0"]


def height_bags(path, node, sensor_path):
    """CHANGE_UM=BAG entries: BAG as bag() prints it, with its --set overrides after a seventh colon."""
    check(path, "calibrate_height", node, ("changes_um", "count", "seed"), ("noise_free",))
    noise_free = node.get("noise_free", False)
    if not isinstance(noise_free, bool):
        fail(path, "calibrate_height.noise_free", "must be true or false")
    entries = []
    for k, change in enumerate(node["changes_um"]):
        where = "calibrate_height.changes_um[%d]" % k
        if not isinstance(change, (int, float)) or change == 0:
            fail(path, where, "must be a non-zero number of um")
        sets = height_sets(sensor_path, change, lambda why: fail(path, where, why))
        if noise_free:
            sets += NOISE_FREE_SETS
        spec = bag(path, "calibrate_height", {"name": "height%g%s" % (change, ".noise_free" if noise_free else ""),
                                              "count": node["count"], "seed": node["seed"] + k})
        entries.append("%g=%s:%s" % (change, spec, ",".join(sets)))
    return " ".join(entries)


def main():
    if len(sys.argv) == 4 and sys.argv[1] == "--height-sets":  # for scripts/unit_tables.sh
        sets = height_sets(sys.argv[2], float(sys.argv[3]), sys.exit)
        print(" ".join("--set " + s for s in sets))
        return
    if len(sys.argv) != 2:
        sys.exit("usage: recipe.py config/recipes/<model>.yaml | recipe.py --height-sets SENSOR.yaml CHANGE_UM")
    path = sys.argv[1]
    try:
        with open(path) as f:
            recipe = yaml.safe_load(f)
    except (OSError, yaml.YAMLError) as e:
        sys.exit("%s: %s" % (path, e))
    check(path, "", recipe, ("sensor", "bags", "train", "calibrate_sigma", "headline"),
          ("set", "baseline", "calibrate_height"))
    if recipe.get("baseline", "centroid") not in ("centroid", "pattern", "none"):
        fail(path, "baseline", "must be centroid, pattern or none")
    check(path, "headline", recipe["headline"], ("alpha_mean_deg", "beta_mean_deg"))
    check(path, "bags", recipe["bags"], ("train", "test", "sigma"))
    train = recipe["train"]
    check(path, "train", train, ("arch", "epochs", "lr", "seed", "centroid_weighting", "feature_corrections"),
          ("lattice_phase", "head", "value_saturation", "spot_readout"))
    sigma = recipe["calibrate_sigma"]
    check(path, "calibrate_sigma", sigma, ("correction_degree", "symmetry"), ("unit_tolerances", "spot_bias_degree", "nominal_bags"))
    sigma_names = [str(b.get("name")) for b in recipe["bags"]["sigma"] if isinstance(b, dict)]
    nominal_bags = sigma.get("nominal_bags", [])
    if not isinstance(nominal_bags, list) or "nominal_bags" in sigma and not nominal_bags:
        fail(path, "calibrate_sigma.nominal_bags", "must be a non-empty list of sigma bag names")
    for name in nominal_bags:
        if str(name) not in sigma_names:
            fail(path, "calibrate_sigma.nominal_bags", "'%s' is not a sigma bag (%s)" % (name, ", ".join(sigma_names)))
    out = {
        "SENSOR": str(recipe["sensor"]),
        "SETS": " ".join(str(s) for s in recipe.get("set", [])),
        "TRAIN_BAGS": " ".join(bag(path, "bags.train[%d]" % i, b) for i, b in enumerate(recipe["bags"]["train"])),
        "TEST_BAG": bag(path, "bags.test", recipe["bags"]["test"]),
        "SIGMA_BAGS": " ".join(bag(path, "bags.sigma[%d]" % i, b) for i, b in enumerate(recipe["bags"]["sigma"])),
        "ARCH": str(train["arch"]),
        "EPOCHS": str(train["epochs"]),
        "LR": str(train["lr"]),
        "TRAIN_SEED": str(train["seed"]),
        "WEIGHTING": str(train["centroid_weighting"]),
        "FEATURES": str(train["feature_corrections"]).lower().replace("true", "on").replace("false", "off"),
        "LATTICE_PHASE": str(train.get("lattice_phase", "")),
        "HEAD": str(train.get("head", "")),
        "VALUE_SATURATION": str(train.get("value_saturation", "")),
        "SPOT_READOUT": str(train.get("spot_readout", "")),
        "CORRECTION": str(sigma["correction_degree"]),
        "SYMMETRY": str(sigma["symmetry"]),
        "UNIT_TOLERANCES": str(sigma.get("unit_tolerances", "keep")),
        "SPOT_BIAS": str(sigma.get("spot_bias_degree", "keep")),
        "NOMINAL_BAGS": " ".join(str(n) for n in nominal_bags),
        "BASELINE": str(recipe.get("baseline", "centroid")),
        "HEIGHT_BAGS": height_bags(path, recipe["calibrate_height"], "%s/../sensors/%s.yaml" % (
            os.path.dirname(os.path.abspath(path)), recipe["sensor"])) if "calibrate_height" in recipe else "",
    }
    for key, value in out.items():
        print("%s=%s" % (key, shlex.quote(value)))


if __name__ == "__main__":
    main()
