#!/usr/bin/python3
"""Reads a shipped model's recipe (config/recipes/<model>.yaml) and prints it as
bash assignments for scripts/train_models.sh. Every key is checked: an unknown
or missing one is an error naming the file and the key.

Keys:
  sensor            config/sensors/<sensor>.yaml
  set               [KEY=V, ...]: dss generate --set overrides of every bag (optional)
  bags.train        [BAG, ...]; bags.test: BAG; bags.sigma: [BAG, ...], where
                    BAG = {name, count, seed, [offset], [sampling], [anomalies]}
                    and the bag is DATA/<model>.<name>.bag
  train             {arch, epochs, lr, seed, centroid_weighting, feature_corrections,
                    [lattice_phase], [head]}: dss train options
  calibrate_sigma   {correction_degree: keep|none|D, symmetry: keep|none|flips|dihedral}
  baseline          centroid (default: dss calibrate on the first training bag) or pattern (the
                    whole-pattern estimator of the sensor's design, for masks whose spots merge)
  headline          {alpha_mean_deg, beta_mean_deg}: the model's mean error on the test bag,
                    which test/test_shipped_models.cpp pins (not printed)
"""
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


def main():
    if len(sys.argv) != 2:
        sys.exit("usage: recipe.py config/recipes/<model>.yaml")
    path = sys.argv[1]
    try:
        with open(path) as f:
            recipe = yaml.safe_load(f)
    except (OSError, yaml.YAMLError) as e:
        sys.exit("%s: %s" % (path, e))
    check(path, "", recipe, ("sensor", "bags", "train", "calibrate_sigma", "headline"), ("set", "baseline"))
    if recipe.get("baseline", "centroid") not in ("centroid", "pattern"):
        fail(path, "baseline", "must be centroid or pattern")
    check(path, "headline", recipe["headline"], ("alpha_mean_deg", "beta_mean_deg"))
    check(path, "bags", recipe["bags"], ("train", "test", "sigma"))
    train = recipe["train"]
    check(path, "train", train, ("arch", "epochs", "lr", "seed", "centroid_weighting", "feature_corrections"),
          ("lattice_phase", "head"))
    sigma = recipe["calibrate_sigma"]
    check(path, "calibrate_sigma", sigma, ("correction_degree", "symmetry"))
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
        "CORRECTION": str(sigma["correction_degree"]),
        "SYMMETRY": str(sigma["symmetry"]),
        "BASELINE": str(recipe.get("baseline", "centroid")),
    }
    for key, value in out.items():
        print("%s=%s" % (key, shlex.quote(value)))


if __name__ == "__main__":
    main()
