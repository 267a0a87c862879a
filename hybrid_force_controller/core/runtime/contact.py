"""The one contact predicate, used by the control law, the simulator and the report."""
from __future__ import annotations

__all__ = ['CONTACT_FORCE_MIN_N', 'ContactDetector', 'contact_threshold', 'in_contact']

CONTACT_FORCE_MIN_N = 0.05


def contact_threshold(f_d: float, minimum: float = CONTACT_FORCE_MIN_N) -> float:
    """
    Return the normal force (N) above which the tool counts as touching.

    ``max(minimum, 0.1 f_d)``, the minimum 0.05 N by default.
    """
    return max(minimum, 0.1 * f_d)


def in_contact(f_n: float, f_d: float = 0.0, minimum: float = CONTACT_FORCE_MIN_N) -> bool:
    """
    Contact from the normal force ``f_n`` the tool exerts (measured or true), N.

    The law (anti-windup), the runtime (with hysteresis, :class:`ContactDetector`), the
    offline scenario and the report (``contact_lost_s``, from the true force with
    ``f_d = 0``) all use this test.
    """
    return f_n > contact_threshold(f_d, minimum)


class ContactDetector:
    """
    Contact with hysteresis on the filtered normal force.

    Contact begins when ``f_n > contact_threshold(f_d)`` and ends once ``f_n`` has stayed
    below half of it for ``dwell`` seconds (noise near the threshold does not chatter,
    and a short dip during a slide is not a loss). Times are the caller's.
    """

    def __init__(self, dwell: float = 0.01) -> None:
        self.dwell = dwell
        self.active = False
        self._t_below: float | None = None

    def reset(self) -> None:
        self.active, self._t_below = False, None

    def update(self, f_n: float, f_d: float, t: float) -> bool:
        """Feed one sample at time ``t``; returns the contact state."""
        enter = contact_threshold(f_d)
        if f_n > enter:
            self.active, self._t_below = True, None
        elif self.active and f_n < 0.5 * enter:
            self._t_below = t if self._t_below is None else self._t_below
            if t - self._t_below >= self.dwell:
                self.active, self._t_below = False, None
        else:
            self._t_below = None
        return self.active
