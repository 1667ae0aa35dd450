"""Link-quality sources (nl80211, wext, file, static) behind one interface, and the monitor.

``SourceName`` is the one list of source names: the config accepts these in
``link.sources``, each source class is named by one, and ``LinkSample.source`` says which
one read a sample.
"""

from enum import StrEnum


class SourceName(StrEnum):
    NL80211 = "nl80211"  # cfg80211 station info over netlink (pyroute2)
    WEXT = "wext"  # /proc/net/wireless, for drivers without nl80211 station stats
    FILE = "file"  # a JSON file written by something else (tests, the demo, the testbed)
    STATIC = "static"  # a fixed Q from the config


__all__ = ["SourceName"]
