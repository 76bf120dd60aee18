#!/usr/bin/env bash
# The tracking prior on a slew through thesis_ca's alias band (docs/results/thesis_ca.md, "Tracking"):
# simulator_node slews the sun along alpha at beta = 0 across the field; two calibration_nodes read
# the same images, one with the image alone and one tracking its own answers
# (~tracking/max_rate_deg_s); the truth and both answers are recorded, and one JSON line per estimator
# says how many images it answered, how many inside the band where the pattern repeats, the largest
# error, the answers off by more than 1 deg (at the mirror-image place) and the tracking node's own
# diagnostics counts (images given the prior, answers farther from the last than the bound allows).
#   scripts/tracking_table.sh [DURATION_S] [RATE_HZ] [SLEW_DEG_S] [MAX_RATE_DEG_S] [SEED] [PROFILE]
# (PROFILE random: each image at a random place, no sequence: what tracking must not be given.)
set -euo pipefail
source "$(dirname "$0")/ros_env.sh"
duration="${1:-300}" rate="${2:-2}" slew="${3:-0.5}" max_rate="${4:-1.0}" seed="${5:-1}" profile="${6:-slew}"
work="$(mktemp -d)"
trap 'rm -rf "$work"' EXIT
cat >"$work/tracking.launch" <<LAUNCH
<launch>
  <include file="\$(find digital_sun_sensor)/launch/simulate.launch">
    <arg name="sensor" value="thesis_ca"/>
    <arg name="rate" value="$rate"/>
    <arg name="profile" value="$profile"/>
    <arg name="seed" value="$seed"/>
  </include>
  <param name="sun_sensor/simulator/slew_rate_deg_s" value="$slew"/>
  <param name="sun_sensor/simulator/slew_heading_deg" value="0.0"/>
  <group ns="sun_sensor">
    <rosparam command="load" ns="calibration" file="\$(find digital_sun_sensor)/config/calibration.yaml"/>
    <param name="calibration/sensor_config" value="thesis_ca"/>
    <param name="calibration/calibration" value="none"/>
    <param name="calibration/inference_symmetry" value="none"/>
    <node pkg="digital_sun_sensor" type="calibration_node" name="calibration" required="true"/>
    <rosparam command="load" ns="calibration_tracking" file="\$(find digital_sun_sensor)/config/calibration.yaml"/>
    <param name="calibration_tracking/sensor_config" value="thesis_ca"/>
    <param name="calibration_tracking/calibration" value="none"/>
    <param name="calibration_tracking/inference_symmetry" value="none"/>
    <param name="calibration_tracking/publish_tf" value="false"/>
    <param name="calibration_tracking/tracking/max_rate_deg_s" value="$max_rate"/>
    <node pkg="digital_sun_sensor" type="calibration_node" name="calibration_tracking" required="true">
      <remap from="angles" to="angles_tracking"/>
      <remap from="sun_vector" to="sun_vector_tracking"/>
    </node>
  </group>
  <node pkg="rosbag" type="record" name="recorder"
        args="-O $work/run.bag /sun_sensor/truth /sun_sensor/angles /sun_sensor/angles_tracking /diagnostics"/>
</launch>
LAUNCH
# roslaunch runs DURATION_S + 60 s; the warm-ups (the simulator's diffraction cache, the estimators'
# canvases) take part of the 60 s, and images are recorded from the simulator's first one.
timeout --signal=INT "$((duration + 60))" roslaunch "$work/tracking.launch" >"$work/launch.log" 2>&1 || true
[ -s "$work/run.bag" ] || { tail -n 30 "$work/launch.log" >&2; echo "no bag recorded" >&2; exit 1; }
/usr/bin/python3 "$(dirname "$0")/tracking_table.py" "$work/run.bag" "$max_rate"
