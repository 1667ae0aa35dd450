"""The one exception the wire codec raises."""


class DecodeError(ValueError):
    """Raised for any input the RTPS codec cannot decode.

    Invariant of ``swarmd.rtps``: decoding functions raise ``DecodeError`` and nothing
    else, for any input whatsoever. Any other exception escaping a decoder is a bug.
    """
