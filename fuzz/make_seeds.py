#!/usr/bin/env python3
"""Writes the seed inputs of every fuzz target (fuzz/seeds/<target>/) from the
package's own files: sensor configs, calibrations, the shipped models'
metadata, and hand-made message payloads. Deterministic; run it again after
a format changes and commit the result."""
import glob
import os
import struct
import sys

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, os.path.join(ROOT, "scripts"))
import container  # noqa: E402  (scripts/container.py)
SEEDS = os.path.join(ROOT, "fuzz", "seeds")


def write(target, name, data):
    os.makedirs(os.path.join(SEEDS, target), exist_ok=True)
    with open(os.path.join(SEEDS, target, name), "wb") as f:
        f.write(data)


def ros_string(s):
    b = s.encode()
    return struct.pack("<I", len(b)) + b


def header(seq=1, frame="sun_sensor_link"):
    return struct.pack("<III", seq, 1700000000, 0) + ros_string(frame)


def main():
    for path in sorted(glob.glob(os.path.join(ROOT, "config", "sensors", "*.yaml"))):
        text = open(path, "rb").read()
        name = os.path.basename(path)[:-5]
        write("sensor_config", name, text)
        write("sensor_config", name + "_set", text + b"\0optics.grid_size=256\0noise.bit_depth=10")
    for path in sorted(glob.glob(os.path.join(ROOT, "models", "*.calib.yaml")))[:3]:
        write("calibration", os.path.basename(path)[:-len(".calib.yaml")], open(path, "rb").read())
    for path in sorted(glob.glob(os.path.join(ROOT, "models", "*.dssmodel")))[:3]:
        name = os.path.basename(path)[:-len(".dssmodel")]
        meta = container.sections(open(path, "rb").read())[0]
        write("metadata", name, meta)
        write("model_file", name + "_metadata", b"\x02\x00" + meta)  # replaces a small model's metadata
    write("model_file", "empty_weights", b"\x02\x01")
    write("model_file", "sections", b"\x01" + b"arch: {}\0weights")
    write("model_file", "raw", b"\x00DSSMODEL" + struct.pack("<II", 2, 2))
    state = (b"sensor: thesis_sa\narch: resnet10_w16\ncentroid_weighting: learned\nfeature_corrections: true\n"
             b"lattice_phase: spotwise\nhead: auto\nbatch_size: 4\nepochs: 2\nseed: 1\ndata_fingerprint: 1\n"
             b"epoch: 0\nstep_in_epoch: 0\nelapsed_s: 0\nbest_val_mean_deg: .inf\nbest_epoch: -1\n")
    write("checkpoint", "state", b"\x01\x00" + state)
    write("checkpoint", "optimizer", b"\x01\x03" + b"PK")
    write("checkpoint", "raw", b"\x00DSSCKPNT" + struct.pack("<II", 1, 4))
    # A 4 x 2 mono8 image, a mono16 one, a truth and a sun vector.
    image8 = (header() + struct.pack("<II", 2, 4) + ros_string("mono8") + struct.pack("<BI", 0, 4) +
              struct.pack("<I", 8) + bytes(range(8)))
    image16 = (header() + struct.pack("<II", 2, 2) + ros_string("mono16") + struct.pack("<BI", 1, 4) +
               struct.pack("<I", 8) + bytes(range(8)))
    truth = (header() + struct.pack("<dd4di", 0.01, -0.02, 0, 0, 0, 0, -1) + b"\x01" + ros_string("truth") +
             ros_string(""))
    vector = header() + struct.pack("<ddd", 0.01, 0.02, 1.0)
    write("bag_messages", "image8", b"\x00" + image8)
    write("bag_messages", "image16", b"\x00" + image16)
    write("bag_messages", "truth", b"\x01" + truth)
    write("bag_messages", "vector", b"\x02" + vector)
    # calibration_node's images: thesis_sa is 512 x 512 mono8 (bit 0: SSCNN).
    blank = bytes(512 * 512)
    lit = bytearray(blank)
    for y in range(250, 262):
        for x in range(250, 262):
            lit[y * 512 + x] = 200
    for flags, name, data in ((0, "centroid_lit", bytes(lit)), (1, "sscnn_lit", bytes(lit))):
        write("image_msg", name, struct.pack("<BIIIB", flags, 512, 512, 512, 5) + b"mono8" + data)
    write("image_msg", "short", struct.pack("<BIIIB", 0, 512, 512, 512, 6) + b"mono16" + bytes(64))
    return 0


if __name__ == "__main__":
    sys.exit(main())
