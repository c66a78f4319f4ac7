"""The LIMO bridge's diagnostics message (``LimoDiagnostics/1``, registered in the protocol).

Kept importable from here for the bridge's own code; ``decode_diagnostics`` is ``decode`` with
the expected type fixed.
"""

from __future__ import annotations

from riskfield.protocol import LimoDiagnostics, decode


def decode_diagnostics(payload: bytes) -> LimoDiagnostics:
    return decode(payload, LimoDiagnostics)


__all__ = ["LimoDiagnostics", "decode_diagnostics"]
