#!/usr/bin/python3
"""Noise of the spot centroids under saturating value weights (docs/sscnn.md#value-saturation).

Reads a noise-free bag and a noisy bag of the same seed (`dss generate ... --set
detector_noise.shot_noise=false --set detector_noise.read_noise_e=0 ...`: the same
angles and true spot centres), takes the lit pixels within RADIUS px of each true
spot centre that lies whole on the detector, and prints per saturation S the RMS of
(noisy - noise-free) centroid per axis, the centroid weighing each pixel value v
(full scale 1) by v / (1 + S v). Bias cancels; what is left is the noise.

  scripts/spot_noise.py CLEAN.bag NOISY.bag [--images N] [--radius PX] [--saturations 0,1,2,4]
"""
import argparse
import math
import struct

import rosbag


def full_scale(path):
    """The sensor's largest code, from the bag's provenance (detector_noise.bit_depth)."""
    with rosbag.Bag(path) as bag:
        for _, msg, _ in bag.read_messages(topics=["/sun_sensor/dataset_info"]):
            for line in msg.data.splitlines():
                if line.strip().startswith("bit_depth:"):
                    return float(2 ** int(line.split(":")[1]) - 1)
    raise SystemExit("spot_noise.py: %s records no detector_noise.bit_depth (not made by dss generate?)" % path)


def frames(path):
    image = None
    with rosbag.Bag(path) as bag:
        for topic, msg, _ in bag.read_messages(topics=["/sun_sensor/image", "/sun_sensor/truth_spots"]):
            if topic.endswith("image"):
                image = msg
            else:
                yield image, msg


def decode(msg):
    if msg.encoding == "mono8":
        return list(bytes(msg.data))
    if msg.encoding == "mono16":
        data = bytes(msg.data)
        return list(struct.unpack((">" if msg.is_bigendian else "<") + "%dH" % (len(data) // 2), data))
    raise SystemExit("spot_noise.py: unsupported encoding " + msg.encoding)


def lit_pixels(values, width, height, cx, cy, radius, top):
    out = []
    for y in range(max(0, int(cy - radius)), min(height - 1, int(cy + radius)) + 1):
        row = y * width
        for x in range(max(0, int(cx - radius)), min(width - 1, int(cx + radius)) + 1):
            v = values[row + x]
            if v and (x - cx) ** 2 + (y - cy) ** 2 <= radius * radius:
                out.append((x, y, v / top))
    return out


def centroid(pixels, saturation):
    s = sx = sy = 0.0
    for x, y, v in pixels:
        w = v / (1.0 + saturation * v)
        s += w
        sx += w * x
        sy += w * y
    return sx / s, sy / s


def main():
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("clean")
    p.add_argument("noisy")
    p.add_argument("--images", type=int, default=100)
    p.add_argument("--radius", type=float, default=30.0)
    p.add_argument("--saturations", default="0,1,2,4")
    a = p.parse_args()
    saturations = [float(s) for s in a.saturations.split(",")]
    differences = {s: [] for s in saturations}
    top = full_scale(a.clean)
    for n, ((clean, spots), (noisy, noisy_spots)) in enumerate(zip(frames(a.clean), frames(a.noisy))):
        if n >= a.images:
            break
        if list(spots.x_px) != list(noisy_spots.x_px):
            raise SystemExit("spot_noise.py: the bags' spot centres differ at image %d (not the same seed?)" % n)
        width, height = clean.width, clean.height
        clean_values, noisy_values = decode(clean), decode(noisy)
        for x, y in zip(spots.x_px, spots.y_px):
            x += (width - 1) / 2.0  # the truth is centred on the detector
            y += (height - 1) / 2.0
            r = a.radius
            if x < r or y < r or x > width - 1 - r or y > height - 1 - r:
                continue
            pc = lit_pixels(clean_values, width, height, x, y, r, top)
            pn = lit_pixels(noisy_values, width, height, x, y, r, top)
            if not pc or not pn:
                continue
            for s in saturations:
                c, m = centroid(pc, s), centroid(pn, s)
                differences[s] += [m[0] - c[0], m[1] - c[1]]
    for s in saturations:
        d = differences[s]
        if not d:
            raise SystemExit("spot_noise.py: no whole spot within the radius")
        print('{"saturation": %g, "spot_axes": %d, "noise_rms_px": %.5f}' % (s, len(d), math.sqrt(sum(v * v for v in d) / len(d))))


if __name__ == "__main__":
    main()
