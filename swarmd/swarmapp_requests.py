"""The control socket's requests in ``SwarmApp`` (``swarmd/swarmapp.py``): ``takeoff``,
``command`` and ``outcomes`` call the swarm core at ``loop.time()``; its ``RequestInvalid``
becomes the control socket's, and each state-changing request is logged with who sent it
(docs/operations.md). Split out of ``swarmapp.py`` by concern at 773 lines (style.md
rule 19).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any, Final

from swarmd.control import STOPPING, PeerCredentials, RequestInvalid
from swarmd.swarm import issuer
from swarmd.swarm.events import SentBy
from swarmd.swarmapp_status import SwarmAppStatus

# command_requested logs the request's kind and targets as the client wrote them; a valid
# one has a short kind and at most a swarm's names, so these only bound a hostile line
MAX_LOGGED_ARG_CHARS: Final = 64
MAX_LOGGED_TARGETS: Final = 64


class ControlRequests(SwarmAppStatus):
    """``ControlServer``'s swarm handlers (``swarmd.control``)."""

    # The state-changing requests (ControlServer's sender handlers): each is logged as
    # ``command_requested`` with who sent it, whatever became of it (docs/operations.md)

    def request_takeoff(
        self, request: Mapping[str, Any], peer: PeerCredentials | None = None
    ) -> dict[str, Any]:
        """Take-off of the targeted nodes that are ready now; ``require_all``: all or none."""
        return self._sent_request("takeoff", self._core().request_takeoff, request, peer)

    def request_command(
        self, request: Mapping[str, Any], peer: PeerCredentials | None = None
    ) -> dict[str, Any]:
        """Any command to the targets as they are: members judge for themselves."""
        return self._sent_request("command", self._core().request_command, request, peer)

    def _sent_request(
        self,
        cmd: str,
        handler: Callable[..., dict[str, Any]],
        request: Mapping[str, Any],
        peer: PeerCredentials | None,
    ) -> dict[str, Any]:
        sent_by = None if peer is None else SentBy(peer.uid, peer.user, peer.pid)
        who = {} if peer is None else peer.log_fields()
        # the request's own words, as data (a client chooses them), cut to what a valid
        # request holds so one log line stays a line's worth
        only = request.get("only")
        asked = {
            "kind": str(request.get("kind", cmd))[:MAX_LOGGED_ARG_CHARS],
            "only": [str(n)[:MAX_LOGGED_ARG_CHARS] for n in only[:MAX_LOGGED_TARGETS]]
            if isinstance(only, list)
            else None,
        }
        try:
            answer = self._request(lambda r, now: handler(r, now, sent_by=sent_by), request)
        except RequestInvalid as exc:
            self.log.info("command_requested", cmd=cmd, **asked, **who, sent=False, error=str(exc))
            raise
        self.log.info(
            "command_requested",
            cmd=cmd,
            **asked,
            **who,
            sent=bool(answer.get("sent")),
            command_id=answer.get("command_id"),
        )
        return answer

    def request_outcomes(self, request: Mapping[str, Any]) -> dict[str, Any]:
        return self._request(self._core().request_outcomes, request)

    def _request(
        self,
        handler: Callable[[Mapping[str, Any], float], dict[str, Any]],
        request: Mapping[str, Any],
    ) -> dict[str, Any]:
        try:
            answer = self._driver().call(lambda now: handler(request, now))
        except issuer.RequestInvalid as exc:
            raise RequestInvalid(str(exc)) from None
        if answer is None:  # the driver closed: the swarm core no longer runs
            # nothing ran (Driver.call): its code tells swarmctl "nothing sent", exit 2,
            # where a bare refusal read as a usage error, 64 (session 16)
            raise RequestInvalid("the daemon is stopping", code=STOPPING)
        return answer
