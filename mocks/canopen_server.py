"""CiA 301 server-side rules that :mod:`canopen`'s :class:`canopen.LocalNode` leaves out, for the
simulated CiA 402 drive (:mod:`hil.mocks.cia402_drive`):

* :class:`BlockSdoServer`: canopen's SDO server plus the **block transfers** (CiA 301 §7.2.4.3.9 -
  7.2.4.3.16, upload and download, CRC-16-CCITT over the data when both sides support it, up to
  127 segments per block). canopen's own server answers a block upload with a plain upload reply
  (allowed by CiA 301 only when the client's protocol switch threshold permits it; canopen's
  client sends 0 and aborts) and aborts every block download.
* :func:`check_pdo_parameter_write`: the SDO aborts a device gives when the host writes its PDO
  communication (0x1400-0x15FF, 0x1800-0x19FF) and mapping (0x1600-0x17FF, 0x1A00-0x1BFF)
  parameters against the procedure of CiA 301 §7.4.8 (the rules of CANopenNode's ``CO_PDO.c``, a
  CiA 301 reference implementation): a mapping is changed only while the PDO is invalid (COB-ID
  bit 31) and its sub-index 0 is 0, else 0x06010000; an entry must name an existing object
  (0x06020000) that may be mapped (PDOMapping, readable for a TPDO, writable for an RPDO), whole
  bytes, at most as long as the object (0x06040041); sub-index 0 (the number of entries) at most 8
  and the entries at most 64 bits together (0x06040042); a COB-ID with bits 11-29 set, or changed
  while the PDO is valid, a transmission type 241-253, an inhibit time or SYNC start value
  written while valid: 0x06090030.
"""

from __future__ import annotations

import binascii
import logging
import struct
from typing import Any

import canopen
from canopen.objectdictionary import ODVariable
from canopen.sdo import SdoAbortedError, SdoServer
from canopen.sdo.constants import (
    CRC_SUPPORTED,
    END_BLOCK_TRANSFER,
    INITIATE_BLOCK_TRANSFER,
    NO_MORE_BLOCKS,
    REQUEST_BLOCK_DOWNLOAD,
    REQUEST_BLOCK_UPLOAD,
    RESPONSE_BLOCK_DOWNLOAD,
    RESPONSE_BLOCK_UPLOAD,
    SDO_STRUCT,
    START_BLOCK_UPLOAD,
)

logger = logging.getLogger(__name__)

#: CiA 301 SDO abort codes used here
ABORT_UNSUPPORTED_ACCESS = 0x06010000
ABORT_NOT_IN_OD = 0x06020000
ABORT_CANNOT_MAP = 0x06040041
ABORT_MAP_LENGTH = 0x06040042
ABORT_INVALID_VALUE = 0x06090030
ABORT_COMMAND = 0x05040001
ABORT_BLOCK_SIZE = 0x05040002
ABORT_SEQUENCE = 0x05040003
ABORT_CRC = 0x05040004
BLOCK_SIZE = 127  # segments per block the server asks for (the most CiA 301 allows)
BLOCK_TRANSFER_RESPONSE = 2
PDO_NOT_VALID = 0x80000000


def crc16(data: bytes) -> int:
    """CRC-16-CCITT of the block transfers (CiA 301 §7.2.4.3.16: x^16 + x^12 + x^5 + 1, initial 0)."""
    return binascii.crc_hqx(bytes(data), 0)


class BlockSdoServer(SdoServer):
    """canopen's SDO server with block upload and block download (module docstring). One transfer
    at a time, as CiA 301 allows per SDO channel; a new initiate request ends a transfer left open."""

    def __init__(self, rx_cobid: int, tx_cobid: int, node: Any) -> None:
        super().__init__(rx_cobid, tx_cobid, node)
        self._block: str | None = None  # "upload" / "download" while a block transfer runs
        self._data = b""
        self._pos = 0  # upload: bytes acknowledged by the client
        self._sent: list[bytes] = []  # upload: segments of the current block
        self._blksize = BLOCK_SIZE
        self._crc = False
        self._seq = 0  # download: last sequence number of this block received in order
        self._received = bytearray()
        self._end_due = False  # download: the last segment was acknowledged, the end request is next
        self._expected_size: int | None = None
        #: block transfers completed (upload, download)
        self.block_transfers = {"upload": 0, "download": 0}

    def on_request(self, can_id: int, data: bytearray, timestamp: float) -> None:
        if self._block == "download" and not self._end_due:
            if data[0] == 0x80:  # the client's abort (a segment's sequence number is never 0)
                self._block = None
                return
            self._block_segment(bytes(data))
            return
        ccs = data[0] & 0xE0
        try:
            if ccs == REQUEST_BLOCK_UPLOAD:
                self._block_upload(bytes(data))
                return
            if ccs == REQUEST_BLOCK_DOWNLOAD:
                self._block_download(bytes(data))
                return
        except SdoAbortedError as exc:
            self._block = None
            self.abort(exc.code)
            return
        except KeyError:
            self._block = None
            self.abort(ABORT_NOT_IN_OD)
            return
        self._block = None
        super().on_request(can_id, data, timestamp)

    # -- block upload ---------------------------------------------------------------------------
    def _block_upload(self, req: bytes) -> None:
        cs = req[0] & 0x03
        if cs == INITIATE_BLOCK_TRANSFER:
            _, index, sub = SDO_STRUCT.unpack_from(req)
            self._index, self._subindex = index, sub
            blksize = req[4]
            if not 1 <= blksize <= 127:
                raise SdoAbortedError(ABORT_BLOCK_SIZE)
            self._data = bytes(self._node.get_data(index, sub, check_readable=True))
            self._pos, self._blksize, self._crc = 0, blksize, bool(req[0] & CRC_SUPPORTED)
            self._block = "upload"
            res = bytearray(8)
            SDO_STRUCT.pack_into(res, 0, RESPONSE_BLOCK_UPLOAD | CRC_SUPPORTED | 0x02, index, sub)  # size indicated
            struct.pack_into("<L", res, 4, len(self._data))
            self.send_response(res)
            return
        if self._block != "upload":
            raise SdoAbortedError(ABORT_COMMAND)
        if cs == START_BLOCK_UPLOAD:
            self._send_block()
        elif cs == BLOCK_TRANSFER_RESPONSE:
            ackseq, blksize = req[1], req[2]
            if not 1 <= blksize <= 127:
                raise SdoAbortedError(ABORT_BLOCK_SIZE)
            self._pos += sum(len(s) for s in self._sent[:ackseq])
            self._blksize = blksize
            if self._pos >= len(self._data) and ackseq == len(self._sent):
                n = (7 - len(self._sent[-1])) if self._sent else 7
                res = bytearray(8)
                res[0] = RESPONSE_BLOCK_UPLOAD | (n << 2) | END_BLOCK_TRANSFER
                struct.pack_into("<H", res, 1, crc16(self._data) if self._crc else 0)
                self.send_response(res)
            else:  # next block, or the rest of this one again from the first segment not acknowledged
                self._send_block()
        elif cs == END_BLOCK_TRANSFER:
            self._block = None
            self.block_transfers["upload"] += 1
        else:
            raise SdoAbortedError(ABORT_COMMAND)

    def _send_block(self) -> None:
        rest = self._data[self._pos:]
        self._sent = [rest[i:i + 7] for i in range(0, min(len(rest), 7 * self._blksize), 7)] or [b""]
        last = self._pos + sum(len(s) for s in self._sent) >= len(self._data)
        for k, seg in enumerate(self._sent, start=1):
            frame = bytearray(8)
            frame[0] = k | (NO_MORE_BLOCKS if last and k == len(self._sent) else 0)
            frame[1:1 + len(seg)] = seg
            self.send_response(frame)

    # -- block download -------------------------------------------------------------------------
    def _block_download(self, req: bytes) -> None:
        cs = req[0] & 0x01
        if cs == INITIATE_BLOCK_TRANSFER:
            _, index, sub = SDO_STRUCT.unpack_from(req)
            self._index, self._subindex = index, sub
            obj = self._node._find_object(index, sub)
            if not obj.writable:
                raise SdoAbortedError(0x06010002)
            self._expected_size = struct.unpack_from("<L", req, 4)[0] if req[0] & 0x02 else None
            self._crc = bool(req[0] & CRC_SUPPORTED)
            self._received, self._seq, self._end_due, self._block = bytearray(), 0, False, "download"
            res = bytearray(8)
            SDO_STRUCT.pack_into(res, 0, RESPONSE_BLOCK_DOWNLOAD | CRC_SUPPORTED, index, sub)
            res[4] = BLOCK_SIZE
            self.send_response(res)
            return
        if self._block != "download" or not self._end_due:
            raise SdoAbortedError(ABORT_COMMAND)
        # end: n bytes of the last segment carry no data; CRC over the whole data
        n = (req[0] >> 2) & 0x07
        data = bytes(self._received[:len(self._received) - n])
        self._block = None
        if self._expected_size is not None and len(data) != self._expected_size:
            raise SdoAbortedError(0x06070010)
        if self._crc and struct.unpack_from("<H", req, 1)[0] != crc16(data):
            raise SdoAbortedError(ABORT_CRC)
        self._node.set_data(self._index, self._subindex, data, check_writable=True)
        self.block_transfers["download"] += 1
        res = bytearray(8)
        res[0] = RESPONSE_BLOCK_DOWNLOAD | END_BLOCK_TRANSFER
        self.send_response(res)

    def _block_segment(self, frame: bytes) -> None:
        """One segment of a block download: kept when in sequence (else ignored); at the block's end
        (sequence number ``BLOCK_SIZE`` or the last segment) the acknowledgement names the last one
        kept, from which the client sends again."""
        seqno, last = frame[0] & 0x7F, bool(frame[0] & NO_MORE_BLOCKS)
        in_order = seqno == self._seq + 1
        if in_order:
            self._seq = seqno
            self._received += frame[1:8]
        if seqno >= BLOCK_SIZE or last:
            res = bytearray(8)
            res[0] = RESPONSE_BLOCK_DOWNLOAD | BLOCK_TRANSFER_RESPONSE
            res[1], res[2] = self._seq, BLOCK_SIZE
            self.send_response(res)
            self._end_due = last and in_order
            self._seq = 0


# ---------------------------------------------------------------------------------------------
# PDO parameters (CiA 301 §7.4.8; CANopenNode CO_PDO.c)


def _u32(node: Any, index: int, sub: int) -> int:
    return int.from_bytes(bytes(node.get_data(index, sub))[:4].ljust(4, b"\0"), "little")


def _entry_bits(node: Any, entry: int, rpdo: bool) -> int:
    """Bits of one mapping entry ``index << 16 | sub << 8 | bits``; SdoAbortedError when it cannot be
    mapped (module docstring)."""
    index, sub, bits = entry >> 16, (entry >> 8) & 0xFF, entry & 0xFF
    if bits % 8:
        raise SdoAbortedError(ABORT_CANNOT_MAP)
    od = node.object_dictionary
    if index not in od:
        raise SdoAbortedError(ABORT_NOT_IN_OD)
    obj = od[index]
    if not isinstance(obj, ODVariable):
        if sub not in obj:
            raise SdoAbortedError(ABORT_NOT_IN_OD)
        obj = obj[sub]
    if not obj.pdo_mappable or not (obj.writable if rpdo else obj.readable) or len(obj) < bits:
        raise SdoAbortedError(ABORT_CANNOT_MAP)
    return bits


def check_pdo_parameter_write(node: canopen.LocalNode, index: int, sub: int, data: bytes) -> bool:
    """Raise the SdoAbortedError a CiA 301 device gives for this write of a PDO parameter (module
    docstring); True when ``index`` is a PDO parameter (the mapping may have changed)."""
    if 0x1400 <= index <= 0x15FF or 0x1800 <= index <= 0x19FF:  # communication parameter
        valid = not _u32(node, index, 1) & PDO_NOT_VALID
        value = int.from_bytes(bytes(data)[:4].ljust(4, b"\0"), "little")
        if sub == 1:
            if value & 0x3FFFF800 or (valid and (value ^ _u32(node, index, 1)) & 0x3FFFFFFF):
                raise SdoAbortedError(ABORT_INVALID_VALUE)
        elif (sub == 2 and 241 <= value <= 253) or (sub in (3, 6) and index >= 0x1800 and valid):
            raise SdoAbortedError(ABORT_INVALID_VALUE)  # reserved transmission type / changed while valid
        return True
    if 0x1600 <= index <= 0x17FF or 0x1A00 <= index <= 0x1BFF:  # mapping parameter
        comm = index - 0x200
        if comm in node.object_dictionary and not _u32(node, comm, 1) & PDO_NOT_VALID:
            raise SdoAbortedError(ABORT_UNSUPPORTED_ACCESS)  # change a mapping only while the PDO is invalid
        rpdo = index < 0x1A00
        if sub == 0:
            n = bytes(data)[0]
            if n > 8:
                raise SdoAbortedError(ABORT_MAP_LENGTH)
            if sum(_entry_bits(node, _u32(node, index, k), rpdo) for k in range(1, n + 1)) > 64:
                raise SdoAbortedError(ABORT_MAP_LENGTH)
        else:
            if bytes(node.get_data(index, 0))[0] != 0:
                raise SdoAbortedError(ABORT_UNSUPPORTED_ACCESS)  # entries only while sub-index 0 is 0
            entry = int.from_bytes(bytes(data)[:4].ljust(4, b"\0"), "little")
            if entry:  # an all-zero entry clears it
                _entry_bits(node, entry, rpdo)
        return True
    return False


__all__ = ["BlockSdoServer", "check_pdo_parameter_write", "crc16"]
