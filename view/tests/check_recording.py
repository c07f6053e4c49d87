#!/usr/bin/env python3
"""Reads a glint-view recording back with the rerun SDK (rerun-sdk==0.36.3) and prints, one per
line, `name value`: the instants on the sensor timeline of the `world/robot` transforms, the sweep
and map point clouds, the keyframes and the lines joining them, and the timeline's first and last
instant (ns since the Unix epoch).

    python3 view/tests/check_recording.py view.rrd
"""

import sys

import pyarrow as pa
from rerun.experimental import RrdReader

TIMELINE = "sensor_time"


def instants(chunk):
    """The chunk's sensor-time instants of rows that hold data, as integers (ns)."""
    batch = chunk.to_record_batch()
    if TIMELINE not in batch.schema.names:
        return []
    column = batch.column(batch.schema.get_field_index(TIMELINE))
    return [v for v in column.cast(pa.int64()).to_pylist() if v is not None]


def columns(chunk):
    return chunk.to_record_batch().schema.names


def main(path):
    times = {
        "transforms": set(),
        "sweep_clouds": set(),
        "map_clouds": set(),
        "keyframes": set(),
        "odometry_lines": set(),
    }
    timelines = set()
    for chunk in RrdReader(path).stream().to_chunks():
        if chunk.is_static:
            continue
        timelines.update(chunk.timeline_names)
        entity = chunk.entity_path
        names = columns(chunk)
        if entity == "/world/robot" and any("Transform3D" in n for n in names):
            times["transforms"].update(instants(chunk))
        elif entity == "/world/robot/sweep" and any("Points3D:positions" in n for n in names):
            times["sweep_clouds"].update(instants(chunk))
        elif entity == "/world/map" and any("Points3D:positions" in n for n in names):
            times["map_clouds"].update(instants(chunk))
        elif entity == "/world/keyframes" and any("Points3D:positions" in n for n in names):
            times["keyframes"].update(instants(chunk))
        elif entity == "/world/keyframes/odometry" and any(
            "LineStrips3D:strips" in n for n in names
        ):
            times["odometry_lines"].update(instants(chunk))
    if TIMELINE not in timelines:
        print(f"no {TIMELINE} timeline; timelines: {sorted(timelines)}", file=sys.stderr)
        return 1
    for name, seen in times.items():
        print(f"{name} {len(seen)}")
    if not times["transforms"]:
        print("no transforms", file=sys.stderr)
        return 1
    print(f"time_min_ns {min(times['transforms'])}")
    print(f"time_max_ns {max(times['transforms'])}")
    print(f"timelines {' '.join(sorted(timelines))}")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1]))
