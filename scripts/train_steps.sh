# Sourced by train_models.sh and train_published.sh (after dss_env.sh, with
# DATA set): the steps every shipped model goes through once its bags exist.
#   train_and_evaluate NAME TRAIN_BAG TEST_BAG SIGMA_BAG EPOCHS ARCH CORRECTION SYMMETRY [DSS TRAIN OPTION...]
# Trains models/NAME.dssmodel unless it exists (resuming DATA/NAME.ckpt when
# present), fits its angle correction (calibrate-sigma --correction-degree
# CORRECTION: a maximum degree, or keep) and its sigma on the sigma bag; with
# a SYMMETRY other than keep (flips, dihedral), sets the model's inference
# symmetry and refits its sigma on the same bag; evaluates it on the test
# bag, then calibrates the centroid baseline on the first 1000 training images
# (models/NAME.calib.yaml) and evaluates it on the same test bag. Results:
# DATA/NAME.*.json and .csv.
train_and_evaluate() {
  local name="$1" train="$2" test="$3" sigma="$4" epochs="$5" arch="$6" correction="$7" symmetry="$8"
  shift 8
  local model="$ROOT/models/$name.dssmodel" calib="$ROOT/models/$name.calib.yaml" ckpt="$DATA/$name.ckpt"
  if [ ! -f "$model" ]; then
    local resume=()
    [ -f "$ckpt" ] && resume=(--resume "$ckpt")
    "$DSS" train --data "$train" --out "$model" --checkpoint "$ckpt" --epochs "$epochs" --arch "$arch" "$@" \
      --lr 5e-4 --seed 1 "${resume[@]}" | tee "$DATA/$name.train.json"
    # smooth angle correction, sigma (level, or a constant per axis) and the input envelope from fresh images
    "$DSS" calibrate-sigma --model "$model" --data "$sigma" --out "$model" --correction-degree "$correction" \
      | tee "$DATA/$name.sigma.json"
    # Estimates averaged over the sensor's mirror images, and their sigma. (A second step because the shipped
    # models got it after their first calibration; in one step the sigma could come out otherwise.)
    if [ "$symmetry" != keep ]; then
      "$DSS" calibrate-sigma --model "$model" --data "$sigma" --out "$model" --symmetry "$symmetry" \
        | tee "$DATA/$name.symmetry.json"
    fi
  fi
  "$DSS" eval --data "$test" --estimator "sscnn:$model" --csv "$DATA/$name.sscnn.csv" | tee "$DATA/$name.sscnn.json"
  "$DSS" calibrate --data "$train" --max-images 1000 --out "$calib" > "$DATA/$name.calibrate.json"
  "$DSS" eval --data "$test" --estimator "centroid:$calib" --csv "$DATA/$name.centroid.csv" \
    | tee "$DATA/$name.centroid.json"
}
