"""Message classes and enums of the wire protocol (generated from protocol/messages.toml)."""

from protocol._generated import *  # noqa: F401,F403
from protocol._generated import MESSAGE_TYPES, MESSAGES_BY_ID, PROTOCOL_VERSION  # noqa: F401
