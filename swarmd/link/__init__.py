"""Link-quality sources (nl80211, wext, file, static) behind one interface, and the monitor."""
