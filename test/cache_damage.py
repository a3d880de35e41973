"""Ways a cache file (a ``.npz`` zip archive) gets damaged, for the corrupt-cache tests.

Each one makes ``np.load`` raise something else: BadZipFile, EOFError, NotImplementedError (a garbled
compression method in the central directory), ValueError, and a CRC or zlib error (garbled member data).
"""

from __future__ import annotations


def damaged(archive: bytes) -> dict[str, bytes]:
    """Damaged copies of the zip archive ``archive``, by what was done to it."""
    directory = archive.rfind(b"PK\x01\x02")  # the first central directory entry
    assert directory > 0, "not a zip archive"
    method = bytearray(archive)
    method[directory + 10] = 99  # compression method 99: "That compression method is not supported"
    stream = bytearray(archive)
    stream[40:60] = b"\xff" * 20  # inside the first member's data
    return {
        "text": b"not a numpy archive",
        "empty": b"",
        "half": archive[: len(archive) // 2],
        "compression method": bytes(method),
        "garbled data": bytes(stream),
    }
