#!/usr/bin/env python3
"""Reads scripts/tracking_table.sh's bag: per estimator one JSON line (answered share, the images the
image alone declined ambiguous_aperture and what this estimator made of them, largest error, answers
more than 1 deg off; the tracking node's diagnostics counts). Usage: tracking_table.py BAG MAX_RATE_DEG_S"""
import json
import math
import sys

import rosbag

bag_path, max_rate = sys.argv[1], float(sys.argv[2])
topics = {"/sun_sensor/truth": {}, "/sun_sensor/angles": {}, "/sun_sensor/angles_tracking": {}}
counts = {}  # the tracking node's last diagnostics values
with rosbag.Bag(bag_path) as bag:
    for topic, msg, _ in bag.read_messages(topics=list(topics) + ["/diagnostics"]):
        if topic == "/diagnostics":
            for status in msg.status:
                if "calibration_tracking" in status.name:
                    counts = {kv.key: kv.value for kv in status.values}
        else:
            topics[topic][msg.header.stamp.to_nsec()] = msg
truth = topics["/sun_sensor/truth"]
alone, tracked = topics["/sun_sensor/angles"], topics["/sun_sensor/angles_tracking"]
stamps = sorted(s for s in truth if s in alone and s in tracked)
if not stamps:
    sys.exit("no image was answered by both estimators")
declined_alone = [s for s in stamps if not alone[s].valid and alone[s].status.startswith("ambiguous_aperture")]
for name, answers, rate in (("image alone", alone, 0.0), ("tracking", tracked, max_rate)):
    errors = []
    for s in stamps:
        a = answers[s]
        if a.valid:
            t = truth[s]
            errors.append(math.degrees(max(abs(a.alpha - t.alpha), abs(a.beta - t.beta))))
    print(json.dumps({
        "estimator": name,
        "tracking_max_rate_deg_s": rate,
        "images": len(stamps),
        "answered_percent": round(100.0 * len(errors) / len(stamps), 2),
        "alone_declined_ambiguous": len(declined_alone),
        "of_those_answered": sum(1 for s in declined_alone if answers[s].valid),
        "truth_alpha_deg_range": [round(math.degrees(min(truth[s].alpha for s in stamps)), 2),
                                  round(math.degrees(max(truth[s].alpha for s in stamps)), 2)],
        "max_error_deg": round(max(errors), 5) if errors else None,
        "off_by_over_1_deg": sum(1 for e in errors if e > 1.0),
        **({"images_with_prior": int(counts.get("images with the tracking prior", -1)),
            "answers_contradicting_prior": int(counts.get("answers contradicting the tracking prior", -1))}
           if rate > 0.0 else {}),
    }))
