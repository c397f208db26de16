"""The uwb-hil wire protocol: one definition (messages.toml), Python codec, generated C side."""

from protocol._generated import MAX_ANCHORS, PROTOCOL_VERSION
from protocol.framing import Frame, FrameDecoder, crc_info, decode_body, encode_body, encode_frame

__all__ = ["MAX_ANCHORS", "PROTOCOL_VERSION", "Frame", "FrameDecoder", "crc_info", "decode_body",
           "encode_body", "encode_frame"]
