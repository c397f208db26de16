"""uwb-hil host harness: flights, numpy twin, bias network, link/device, streaming, reports."""

__version__ = "0.1.0"
