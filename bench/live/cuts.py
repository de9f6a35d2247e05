"""Sequences with frames cut out, made of symbolic links to the originals: a camera that jumps
to a mapped place (relocalisation) or to an unmapped one (a new map). Used by
bench/live/kidnap.py and bench/ab/capture.py."""
import os
import re


def frame_number(line):
    """7-Scenes list line -> its frame number (`rgb/frame-000123.color.jpg` -> 123)."""
    return int(re.search(r"frame-(\d+)", line).group(1))


def seven_scenes_cut(root, seven, first, last):
    """7-Scenes (the folder `seven`) without frames first..=last, as
    root/seven_scenes_redkitchen_1000 (root is also run_peer.py's data root). Returns that folder."""
    seq = os.path.join(root, "seven_scenes_redkitchen_1000")
    os.makedirs(seq, exist_ok=True)
    for f in ["rgb", "depth", "pose", "camera-intrinsics.txt", "gravity-direction.txt", "groundtruth_tum.txt"]:
        link = os.path.join(seq, f)
        if not os.path.lexists(link):
            os.symlink(os.path.join(seven, f), link)
    for f in ["rgb.txt", "depth.txt", "associations.txt"]:
        with open(os.path.join(seven, f)) as src, open(os.path.join(seq, f), "w") as dst:
            for line in src:
                if line.startswith("#") or not line.strip() or not first <= frame_number(line) <= last:
                    dst.write(line)
    return seq


def kitti_cut(seq, source, first, last):
    """The KITTI-layout folder `source` without frames first..=last, as `seq` (renumbered links;
    a missing right image stays missing). Returns `seq`."""
    for cam in ["image_0", "image_1"]:
        os.makedirs(os.path.join(seq, cam), exist_ok=True)
    times = [l for l in open(os.path.join(source, "times.txt")) if l.strip()]
    poses = [l for l in open(os.path.join(source, "poses.txt")) if l.strip()]
    keep = [i for i in range(len(times)) if not first <= i <= last]
    with open(os.path.join(seq, "times.txt"), "w") as ft, open(os.path.join(seq, "poses.txt"), "w") as fp:
        for j, i in enumerate(keep):
            ft.write(times[i])
            fp.write(poses[i])
            for cam in ["image_0", "image_1"]:
                link = os.path.join(seq, cam, f"{j:06d}.png")
                if not os.path.lexists(link) and os.path.exists(os.path.join(source, cam, f"{i:06d}.png")):
                    os.symlink(os.path.join(source, cam, f"{i:06d}.png"), link)
    link = os.path.join(seq, "calib.txt")
    if not os.path.lexists(link):
        os.symlink(os.path.join(source, "calib.txt"), link)
    return seq
