"""An MCAP file rewritten small: every message in time order, in large zstd chunks, without
message indexes.

A message index holds 16 bytes per message, outside the compressed chunks: a quarter of a
compressed recording of a run (``replay --record``), whose messages are small. Readers use it
to read in time order without reading the file in order; a file whose messages are stored
in time order needs none of it:

* Foxglove opens a file without chunk indexes as an unindexed file and reads it whole (its
  indexed reader refuses chunk indexes without message indexes, so none are written);
* ``ros2 bag play`` (rosbag2_storage_mcap) plays it in file order, after one warning that it
  cannot read in receive-time order without message indexes;
* rosbags and the ``mcap`` package read it in file order (rosbags checks the order).

The summary keeps the schemas, channels, statistics (message counts, start and end) and the
metadata records (rosbag2's ``serialized_metadata``) with their index.
"""
from __future__ import annotations

import os
import struct
import zlib
from pathlib import Path

#: Uncompressed bytes per chunk. zstd starts afresh in each chunk: few large chunks let it find
#: what repeats from scan to scan (on leg_tracker's person_following, 32 MiB chunks are 3 %
#: smaller than 8 MiB ones at level 12).
CHUNK_BYTES = 32 * 2 ** 20


def zstd():
    """The zstd module: the standard library's from Python 3.14, else rosbags' backport."""
    try:
        from compression import zstd as module
    except ImportError:
        from backports import zstd as module
    return module


def zstd_options() -> dict:
    """Level 12 over a chunk's whole length: 0.9 s for a recording of person_following (67 MB
    of messages). zstd's optimal parser (levels 16 to 19) would save 5 to 13 % more for 4 to
    18 s, and make recording a run take about twice as long as replaying it, or more."""
    p = zstd().CompressionParameter
    return {p.compression_level: 12, p.window_log: CHUNK_BYTES.bit_length() - 1}


def compact_mcap(recording: str | Path, chunk_bytes: int = CHUNK_BYTES) -> None:
    """Rewrite the MCAP file of the rosbag2 ``recording`` (a folder) in place as the module doc
    says: written beside it, then moved over it; on an error the original stays and the
    partial copy is removed."""
    (path,) = Path(recording).glob('*.mcap')
    tmp = path.with_name(path.name + '.compact')
    try:
        with tmp.open('w+b') as dst:
            _rewrite(Path(recording), path, _Output(dst), chunk_bytes)
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)


class _Output:
    """MCAP records written to a file: where each lands, and the statistics of the messages
    written in chunks."""

    def __init__(self, file):
        from mcap.data_stream import RecordBuilder

        self.file, self._builder = file, RecordBuilder()
        self.counts: dict[int, int] = {}        # messages per channel id
        self.first = self.last = 0              # log times of the first and last message
        self.chunks = 0

    def write(self, *records) -> tuple[int, int]:
        """Write ``records``; their offset in the file and length."""
        offset = self.file.tell()
        for record in records:
            record.write(self._builder)
        self.file.write(self._builder.end())
        return offset, self.file.tell() - offset

    def write_chunk(self, messages: bytearray, times: list[int], compress) -> None:
        """A chunk of ``messages`` (Message records, ``compress``-ed) whose log times are
        ``times``, in order."""
        from mcap.records import Chunk

        data = bytes(messages)
        self.write(Chunk(compression='zstd', data=compress(data),
                         message_start_time=times[0], message_end_time=times[-1],
                         uncompressed_crc=zlib.crc32(data), uncompressed_size=len(data)))
        self.first = times[0] if not self.chunks else self.first
        self.last = times[-1]
        self.chunks += 1


#: A Message record's opcode, length and fields before its data (MCAP specification).
_MESSAGE = struct.Struct('<BQHIQQ')
_MESSAGE_OPCODE = 0x05


def _rewrite(recording: Path, path: Path, out: _Output, chunk_bytes: int) -> None:
    from mcap.opcode import Opcode
    from mcap.reader import make_reader
    from mcap.records import DataEnd, Footer, MetadataIndex, Statistics, SummaryOffset
    from mcap.writer import MCAP0_MAGIC
    from rosbags.rosbag2 import Reader

    with path.open('rb') as src:
        reader = make_reader(src)
        header, summary = reader.get_header(), reader.get_summary()
        metadata = list(reader.iter_metadata())
    schemas = list(summary.schemas.values()) if summary else []
    channels = list(summary.channels.values()) if summary else []
    channel_of = {c.topic: c.id for c in channels}      # one channel per topic
    options = zstd_options()

    def compress(data: bytes) -> bytes:
        return zstd().compress(data, options=options)

    out.file.write(MCAP0_MAGIC)
    out.write(header, *schemas, *channels)  # linear readers meet them before the data
    chunk, times = bytearray(), []
    with Reader(recording) as messages:     # in time order, equal times as written
        for connection, t, data in messages.messages():
            channel = channel_of[connection.topic]
            chunk += _MESSAGE.pack(_MESSAGE_OPCODE, 22 + len(data), channel, 0, t, t)
            chunk += data
            times.append(t)
            out.counts[channel] = out.counts.get(channel, 0) + 1
            if len(chunk) >= chunk_bytes:
                out.write_chunk(chunk, times, compress)
                chunk, times = bytearray(), []
    if times:
        out.write_chunk(chunk, times, compress)
    indexes = [MetadataIndex(*out.write(record), name=record.name) for record in metadata]
    out.write(DataEnd(data_section_crc=0))

    statistics = Statistics(
        message_count=sum(out.counts.values()), schema_count=len(schemas),
        channel_count=len(channels), attachment_count=0, metadata_count=len(metadata),
        chunk_count=out.chunks, message_start_time=out.first, message_end_time=out.last,
        channel_message_counts={c.id: out.counts.get(c.id, 0) for c in channels})
    summary_start, offsets = out.file.tell(), []
    for opcode, records in ((Opcode.SCHEMA, schemas), (Opcode.CHANNEL, channels),
                            (Opcode.STATISTICS, [statistics]),
                            (Opcode.METADATA_INDEX, indexes)):
        if records:
            offsets.append(SummaryOffset(opcode, *out.write(*records)))
    offsets_start = out.file.tell()
    out.write(*offsets)
    out.file.seek(summary_start)            # the footer's CRC covers the summary and itself
    crc = zlib.crc32(struct.pack('<BQQQ', Opcode.FOOTER, 20, summary_start, offsets_start),
                     zlib.crc32(out.file.read()))
    out.write(Footer(summary_start=summary_start, summary_offset_start=offsets_start,
                     summary_crc=crc))
    out.file.write(MCAP0_MAGIC)
