#!/usr/bin/env python3
"""A Rerun blueprint (layout) for dwslam's live view: the 3D world large on the left; the
image with its tracked points, the tracking counts and the frame times on the right; the
log below. `rerun VIEW.rrd dwslam.rbl` opens a recording with it; `dwslam run --view`
without it gets Rerun's automatic layout.

    python3 bench/view/blueprint.py OUT.rbl      (needs pip install rerun-sdk==0.36.3)
    python3 bench/view/blueprint.py --send URL VIEW.rrd
        (to a running viewer's gRPC server, e.g. rerun+http://127.0.0.1:9876/proxy, for the
        recording of VIEW.rrd)
"""

import sys

import rerun as rr
import rerun.blueprint as rrb


def blueprint() -> rrb.Blueprint:
    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Spatial3DView(name="map", origin="/world"),
            rrb.Vertical(
                rrb.Spatial2DView(name="image", origin="/world/camera/image"),
                rrb.TimeSeriesView(name="tracked points", origin="/tracking/points"),
                rrb.TimeSeriesView(name="ms per frame", origin="/timing"),
                rrb.TextLogView(name="log", origin="/tracking/log"),
                row_shares=[3, 2, 2, 2],
            ),
            column_shares=[3, 2],
        ),
        collapse_panels=True,
    )


if __name__ == "__main__":
    if len(sys.argv) == 4 and sys.argv[1] == "--send":
        from rerun.experimental import RrdReader

        # The blueprint goes with the recording it lays out (the same recording id).
        recording = RrdReader(sys.argv[3]).recordings()[0]
        rr.init(recording.application_id, recording_id=recording.recording_id)
        rr.connect_grpc(sys.argv[2])
        rr.send_blueprint(blueprint(), make_active=True, make_default=True)
        rr.disconnect()
        print(f"sent the blueprint to {sys.argv[2]}")
    elif len(sys.argv) == 2:
        blueprint().save("dwslam", sys.argv[1])
        print(f"wrote {sys.argv[1]}")
    else:
        sys.exit(__doc__)
