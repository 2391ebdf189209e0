#!/usr/bin/env python3
"""Checks an MCAP log of `motm run --mcap` with the Python `mcap` and `mcap-protobuf-support`
readers, independently of the logger's own code: every message of every protobuf channel is
decoded, and every `timestamp` it holds (the message's own, or those of its transforms, scene
entities and deletions) must be non-zero and within a tolerance (1 ms) of the record's log time.

    pip install mcap mcap-protobuf-support
    python3 services/logger/tools/check_stamps.py run.mcap [--tolerance-ms 1]

Prints per topic the messages, the timestamps checked and the largest |timestamp - log time|;
exits 1 when a timestamp is zero, missing or off by more than the tolerance, or when the log has
no protobuf channel.
"""

import argparse
import sys
from collections import defaultdict

from mcap.reader import make_reader
from mcap_protobuf.decoder import DecoderFactory


TIMESTAMP = "google.protobuf.Timestamp"


def timestamps(message):
    """Every google.protobuf.Timestamp field named `timestamp` in `message`, at any depth, as
    ns. (The decoder builds its classes from the file's schemas: they are matched by name.)"""
    found = []
    for field, value in message.ListFields():
        if field.message_type is None:
            continue
        values = value if field.is_repeated else [value]
        for v in values:
            if field.message_type.full_name != TIMESTAMP:
                found.extend(timestamps(v))
            elif field.name == "timestamp":
                found.append(v.seconds * 1_000_000_000 + v.nanos)
    return found


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("mcap", help="the MCAP file")
    parser.add_argument("--tolerance-ms", type=float, default=1.0)
    args = parser.parse_args()
    tolerance_ns = int(args.tolerance_ms * 1e6)

    messages = defaultdict(int)
    stamps = defaultdict(int)
    worst_ns = defaultdict(int)
    failures = defaultdict(int)
    first_failure = {}
    with open(args.mcap, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        summary = reader.get_summary()
        protobuf = sorted(
            {
                c.topic
                for c in (summary.channels.values() if summary else [])
                if c.message_encoding == "protobuf"
            }
        )
        for schema, channel, record, decoded in reader.iter_decoded_messages(
            topics=protobuf or [""]
        ):
            topic = channel.topic
            messages[topic] += 1
            found = timestamps(decoded)
            if not found:
                failures[topic] += 1
                first_failure.setdefault(topic, f"no timestamp in a {schema.name}")
            for ns in found:
                stamps[topic] += 1
                delta = abs(ns - record.log_time)
                worst_ns[topic] = max(worst_ns[topic], delta)
                if ns == 0 or delta > tolerance_ns:
                    failures[topic] += 1
                    first_failure.setdefault(
                        topic,
                        f"timestamp {ns} ns, log time {record.log_time} ns "
                        f"(|Δ| {delta / 1e6:.3f} ms)",
                    )

    if not messages:
        print(f"{args.mcap}: no protobuf channel", file=sys.stderr)
        return 1
    print(f"{'topic':<20} {'messages':>9} {'stamps':>9} {'max |Δ| ms':>11} {'failed':>7}")
    for topic in sorted(messages):
        print(
            f"{topic:<20} {messages[topic]:>9} {stamps[topic]:>9} "
            f"{worst_ns[topic] / 1e6:>11.6f} {failures[topic]:>7}"
        )
    for topic, why in sorted(first_failure.items()):
        print(f"{topic}: first failure: {why}", file=sys.stderr)
    return 1 if any(failures.values()) else 0


if __name__ == "__main__":
    sys.exit(main())
