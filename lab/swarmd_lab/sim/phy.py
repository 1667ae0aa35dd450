"""802.11g (ERP-OFDM) physical layer numbers: airtime, path loss, SNR and packet error rate.

Everything here is a pure function of its arguments. The constants are IEEE 802.11-2016
clause 18 (OFDM) and 19 (ERP) values with the short slot, and ns-3's defaults where the
standard leaves a choice (transmit power, noise figure, log-distance exponent), because the
paper's testbed is ns-3 (section 5.1). ``docs/simulator.md`` lists where this departs from
the standard.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Final

import numpy as np
import numpy.typing as npt

FloatArray = npt.NDArray[np.float64]

# IEEE 802.11-2016 Table 19-5 (ERP, short slot) and 17-21 (OFDM timing)
SLOT_S: Final = 9e-6
SIFS_S: Final = 10e-6
DIFS_S: Final = SIFS_S + 2 * SLOT_S  # 28 us
CW_MIN: Final = 15
CW_MAX: Final = 1023
PREAMBLE_S: Final = 20e-6  # 16 us PLCP preamble + 4 us SIGNAL
SYMBOL_S: Final = 4e-6
SIGNAL_EXTENSION_S: Final = 6e-6  # ERP-OFDM in 2.4 GHz (19.3.2.4)
SERVICE_TAIL_BITS: Final = 16 + 6
# aCCATime: a station cannot sense a transmission that started less than this ago, so two
# stations whose backoff ends within this window both transmit and collide (17.4.4)
CCA_WINDOW_S: Final = 4e-6

# MAC header 24 + FCS 4 + LLC/SNAP 8 + IPv4 20 + UDP 8: bytes a UDP payload gains on the air
UDP_FRAME_OVERHEAD: Final = 24 + 4 + 8 + 20 + 8
# the same with a 32-byte TCP header (20 + timestamps option) instead of UDP's 8
TCP_FRAME_OVERHEAD: Final = 24 + 4 + 8 + 20 + 32
ACK_BYTES: Final = 14
# largest UDP payload in one 1500-byte IP packet; the simulator never fragments
MAX_UDP_PAYLOAD: Final = 1472

# ERP-OFDM rates (Mb/s) and the SNR (dB) at which a 1000-byte frame sees 10 % PER. The
# figures approximate ns-3's NIST error-rate model for 20 MHz OFDM (BPSK 1/2 ... 64-QAM 3/4).
RATES_MBPS: Final = (6, 9, 12, 18, 24, 36, 48, 54)
SNR10_DB: Final = {6: 4.0, 9: 6.0, 12: 7.0, 18: 9.5, 24: 12.5, 36: 16.5, 48: 20.5, 54: 22.0}
# mandatory ERP basic rate set: multicast goes at the lowest, an ACK at the highest <= data
BASIC_RATES_MBPS: Final = (6, 12, 24)
# waterfall width: PER of a 1000-byte frame falls from 90 % to 10 % over 4.4 * this (dB);
# coded OFDM waterfalls are steep (about 2 dB from 90 % to 10 %)
PER_SLOPE_DB: Final = 0.5
PER_REFERENCE_BYTES: Final = 1000


def airtime_s(mpdu_bytes: int, rate_mbps: int) -> float:
    """Duration of one ERP-OFDM PPDU carrying ``mpdu_bytes`` (PSDU) at ``rate_mbps``."""
    bits_per_symbol = 4 * rate_mbps
    symbols = math.ceil((SERVICE_TAIL_BITS + 8 * mpdu_bytes) / bits_per_symbol)
    return PREAMBLE_S + SYMBOL_S * symbols + SIGNAL_EXTENSION_S


def ack_rate_mbps(data_rate_mbps: int) -> int:
    """Control response rate: the highest basic rate not above the data rate (10.7.6.5)."""
    return max(r for r in BASIC_RATES_MBPS if r <= data_rate_mbps)


def ack_timeout_s(data_rate_mbps: int) -> float:
    """How long a sender waits for the ACK after its frame ends (10.3.2.9: SIFS + slot + ACK)."""
    return SIFS_S + SLOT_S + airtime_s(ACK_BYTES, ack_rate_mbps(data_rate_mbps))


@dataclass(frozen=True, slots=True)
class Radio:
    """Link budget: log-distance path loss, ns-3 defaults (LogDistancePropagationLossModel,
    YansWifiPhy TxPower 16.0206 dBm, RxNoiseFigure 7 dB, 20 MHz thermal noise -101 dBm)."""

    tx_power_dbm: float = 16.0206
    reference_loss_db: float = 40.05  # Friis free space at 1 m, 2.412 GHz
    exponent: float = 3.0
    noise_floor_dbm: float = -101.0 + 7.0
    # a receiver decodes nothing below this SNR (preamble detection, ns-3 RxSensitivity -101)
    min_snr_db: float = -3.0
    # energy/preamble detect: a station defers to signals above this level (CCA, -82 dBm)
    cca_threshold_dbm: float = -82.0

    def rx_power_dbm(self, distance_m: FloatArray) -> FloatArray:
        d = np.maximum(distance_m, 1.0)
        return self.tx_power_dbm - (self.reference_loss_db + 10.0 * self.exponent * np.log10(d))

    def snr_db(self, distance_m: FloatArray) -> FloatArray:
        return self.rx_power_dbm(distance_m) - self.noise_floor_dbm


def per(snr_db: FloatArray | float, mpdu_bytes: int, rate_mbps: int) -> FloatArray:
    """Packet error rate of an ``mpdu_bytes`` frame at ``rate_mbps`` for a given SNR/SINR.

    A logistic waterfall in dB for the reference 1000-byte frame, 10 % at ``SNR10_DB``;
    longer frames fail more often: 1 - (1 - PER_1000) ** (bytes / 1000).
    """
    snr50 = SNR10_DB[rate_mbps] - PER_SLOPE_DB * math.log(9.0)
    x = np.clip((np.asarray(snr_db, dtype=np.float64) - snr50) / PER_SLOPE_DB, -50.0, 50.0)
    per_ref = 1.0 / (1.0 + np.exp(x))
    result: FloatArray = 1.0 - (1.0 - per_ref) ** (mpdu_bytes / PER_REFERENCE_BYTES)
    return result


def min_snr_db(rate_mbps: int, *, target_per: float = 0.1, mpdu_bytes: int = 1500) -> float:
    """The SNR (dB) above which an ``mpdu_bytes`` frame at ``rate_mbps`` fails less often
    than ``target_per``: ``per`` solved for the SNR."""
    per_ref = 1.0 - (1.0 - target_per) ** (PER_REFERENCE_BYTES / mpdu_bytes)
    snr50 = SNR10_DB[rate_mbps] - PER_SLOPE_DB * math.log(9.0)
    return snr50 + PER_SLOPE_DB * math.log(1.0 / per_ref - 1.0)


def ideal_rate_mbps(snr_db: float, *, target_per: float = 0.1, mpdu_bytes: int = 1500) -> int:
    """The highest rate whose PER for a full-size frame stays under ``target_per`` (ns-3's
    IdealWifiManager picks rates by SNR threshold the same way); never below 6 Mb/s."""
    best = RATES_MBPS[0]
    for rate in RATES_MBPS:
        if snr_db >= min_snr_db(rate, target_per=target_per, mpdu_bytes=mpdu_bytes):
            best = rate
    return best
