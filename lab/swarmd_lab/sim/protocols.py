"""The protocols the simulator can run, by name, and how to build one node of each."""

from __future__ import annotations

from typing import TYPE_CHECKING, Final

import numpy as np

from swarmd.discovery.config import EngineConfig
from swarmd_lab.sim.dds_model import CYCLONE, FASTDDS, DdsNode
from swarmd_lab.sim.node import NodeContext, SimNode
from swarmd_lab.sim.swarmd_node import SwarmdNode, SwarmdShared, link_sample_for
from swarmd_lab.sim.workload import COMMANDER
from swarmd_lab.sim.zenoh_model import ZenohNode
from swarmd_lab.testing import make_bundle

if TYPE_CHECKING:
    from swarmd_lab.sim.channel import Channel
    from swarmd_lab.sim.runner import Scenario

# swarmd-auth: swarmd with the SPDP authenticator's bytes and freshness on every datagram
# (modelled_auth: no Ed25519 arithmetic), for the issue-10 byte and packet figures
PROTOCOLS: Final = ("swarmd", "swarmd-auth", "fastdds-model", "cyclone-model", "zenoh-model")


def build_nodes(scenario: Scenario, contexts: list[NodeContext], channel: Channel) -> list[SimNode]:
    """One node per context, running ``scenario.protocol``."""
    name = scenario.protocol
    if name in ("swarmd", "swarmd-auth"):
        bundle = make_bundle(scenario.n)
        config = EngineConfig(mode=scenario.swarmd_mode, vouch=scenario.vouch)  # type: ignore[arg-type]
        shared = SwarmdShared.of(bundle, config)
        shared.modelled_auth = name == "swarmd-auth"
        snr = channel.snr_db.copy()
        np.fill_diagonal(snr, np.nan)
        # what each drone's link monitor reads: the median SNR of the others' frames
        medians = np.nanmedian(snr, axis=1) if scenario.n > 1 else np.zeros(1)
        return [
            SwarmdNode(ctx, shared, link_sample_for(float(medians[ctx.index]))) for ctx in contexts
        ]
    if name in ("fastdds-model", "cyclone-model"):
        timing = FASTDDS if name == "fastdds-model" else CYCLONE
        # the workload topic: members write swarm/ready, the commander reads it
        return [
            DdsNode(
                ctx,
                timing,
                writers=0 if ctx.index == COMMANDER else 1,
                readers=1 if ctx.index == COMMANDER else 0,
            )
            for ctx in contexts
        ]
    if name == "zenoh-model":
        return [ZenohNode(ctx) for ctx in contexts]
    raise ValueError(f"--protocol {name!r} is unknown; use one of {', '.join(PROTOCOLS)}")
