#!/usr/bin/env python3
"""Decode every message of a chaoscope recording with standard Python tools.

Usage: check_mcap.py FILE.mcap EXPECTED_MESSAGES

Uses the `mcap` reader with `mcap-protobuf-support` (the schema records carry a
FileDescriptorSet), checks that every message decodes, that vectors are finite, and that the
message count matches. Prints one JSON line of counts per topic. Writes nothing.
"""
import json
import math
import sys

from mcap.reader import make_reader
from mcap_protobuf.decoder import DecoderFactory


def main() -> int:
    path, expected = sys.argv[1], int(sys.argv[2])
    counts = {}
    with open(path, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        summary = reader.get_summary()
        assert summary is not None, "no summary section"
        assert summary.chunk_indexes, "no chunk indexes"
        metadata = {m.name: m.metadata for m in reader.iter_metadata()}
        assert "chaoscope.run" in metadata, metadata.keys()
        assert "config_toml" in metadata["chaoscope.run"]
        for schema, channel, message, decoded in reader.iter_decoded_messages():
            assert schema.encoding == "protobuf", schema.encoding
            counts[channel.topic] = counts.get(channel.topic, 0) + 1
            for field in ("state", "separations", "stretch"):
                values = getattr(decoded, field, None)
                if values is not None:
                    assert all(math.isfinite(v) for v in values), f"non-finite {field} on {channel.topic}"
    total = sum(counts.values())
    print(json.dumps({"total": total, "topics": counts}))
    if total != expected:
        print(f"expected {expected} messages, decoded {total}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
