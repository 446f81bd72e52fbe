"""Reads an episode recording with Python's `mcap` package and decodes every
message with the schema the file carries (protobuf through
`mcap-protobuf-support`, JSON checked against its JSON schema), as Foxglove
does. Prints one JSON object describing what it found; exits non-zero on any
message it cannot decode.

Usage: python3 read_recording.py FILE.mcap [LAYOUT.json]
With a layout, also lists the layout's topics the file does not have.
"""

import json
import sys

from mcap.reader import make_reader
from mcap_protobuf.decoder import DecoderFactory

JSON_TYPES = {
    "integer": int,
    "number": (int, float),
    "string": str,
    "boolean": bool,
    "object": dict,
    "array": list,
}


def check_json(value, schema, where):
    """Every property the schema names is present with its type."""
    expected = JSON_TYPES[schema["type"]]
    if isinstance(value, bool) and schema["type"] in ("integer", "number"):
        raise ValueError(f"{where}: a boolean where a {schema['type']} belongs")
    if not isinstance(value, expected):
        raise ValueError(f"{where}: {value!r} is not a {schema['type']}")
    for key, sub in schema.get("properties", {}).items():
        if key not in value:
            raise ValueError(f"{where}: no {key!r}")
        check_json(value[key], sub, f"{where}.{key}")


def layout_topics(layout):
    topics = set()
    for config in layout["configById"].values():
        mode = config.get("imageMode", {})
        for key in ("imageTopic", "calibrationTopic"):
            if key in mode:
                topics.add(mode[key])
        topics.update(config.get("topics", {}))
        for path in config.get("paths", []):
            topics.add(path["value"].split(".")[0])
        if "topicPath" in config:
            topics.add(config["topicPath"].split(".")[0])
    return topics


def main():
    protobuf = DecoderFactory()
    found = {}
    with open(sys.argv[1], "rb") as f:
        reader = make_reader(f)
        for schema, channel, message in reader.iter_messages():
            topic = channel.topic
            entry = found.setdefault(
                topic,
                {"schema": schema.name, "encoding": channel.message_encoding, "messages": 0},
            )
            entry["messages"] += 1
            if channel.message_encoding == "protobuf":
                decode = protobuf.decoder_for(channel.message_encoding, schema)
                if decode is None:
                    raise ValueError(f"{topic}: no protobuf decoder for {schema.name}")
                decoded = decode(message.data)
                if schema.name == "foxglove.RawImage":
                    if len(decoded.data) != decoded.step * decoded.height:
                        raise ValueError(f"{topic}: {len(decoded.data)} bytes for {decoded.step} x {decoded.height}")
                    entry["size"] = [decoded.width, decoded.height]
                    entry["image_encoding"] = decoded.encoding
                elif schema.name == "foxglove.Grid":
                    entry["fields"] = [field.name for field in decoded.fields]
                    entry["columns"] = decoded.column_count
                    rows = len(decoded.data) // decoded.row_stride
                    entry["rows"] = rows
                elif schema.name == "foxglove.SceneUpdate":
                    entry["entities"] = len(decoded.entities)
                    entry["triangles"] = sum(
                        len(t.indices) // 3 for e in decoded.entities for t in e.triangles
                    )
                    entry["metadata_keys"] = sorted(
                        {kv.key for e in decoded.entities for kv in e.metadata}
                    )
                elif schema.name == "foxglove.CameraCalibration":
                    entry["K"] = list(decoded.K)
                elif schema.name == "foxglove.FrameTransform":
                    entry["frames"] = [decoded.parent_frame_id, decoded.child_frame_id]
            elif channel.message_encoding == "json":
                if schema.encoding != "jsonschema":
                    raise ValueError(f"{topic}: JSON message with a {schema.encoding} schema")
                check_json(json.loads(message.data), json.loads(schema.data), topic)
            else:
                raise ValueError(f"{topic}: unknown message encoding {channel.message_encoding}")
    out = {"topics": found}
    if len(sys.argv) > 2:
        with open(sys.argv[2]) as f:
            wanted = layout_topics(json.load(f))
        out["layout_topics_missing"] = sorted(wanted - set(found))
    print(json.dumps(out))


if __name__ == "__main__":
    main()
