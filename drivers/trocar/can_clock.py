"""Which clock ``can.Message.timestamp`` is on, per python-can interface.

python-can fills ``Message.timestamp`` (float seconds) in the interface backend, so what it
means depends on the adapter. Interfaces listed here give a stamp taken before the message
reached Python (in the adapter or the kernel); the trocar uses it as its device time. For the
others (and with ``clock = "host"``) the device time is the host receive time.
"""

from __future__ import annotations

from vbfe.common.errors import DeviceError

CLOCK_CHOICES = ("auto", "interface", "host")

INTERFACE_CLOCKS: dict[str, str] = {
    "socketcan": "kernel receive time of the frame (SO_TIMESTAMPNS, CLOCK_REALTIME, ns)",
    "pcan": "PCAN adapter hardware time (µs) since boot, shifted to epoch by python-can",
    "kvaser": "Kvaser adapter hardware timer (canlib), offset to epoch at bus start",
    "vector": "Vector XL driver hardware time (ns), offset to epoch at bus start",
    "ixxat": "IXXAT adapter hardware time, offset to epoch at bus start",
    "neovi": "Intrepid neoVI hardware time",
    "gs_usb": "gs_usb adapter hardware time (µs) of the received frame",
    "virtual": "the sender's time.time() at send (its own timestamp with preserve_timestamps)",
}
HOST_CLOCK = "host receive time (the interface gives no timestamp of its own)"


def check_clock_choice(clock: str) -> str:
    """``clock`` when it is one of :data:`CLOCK_CHOICES`, else a DeviceError naming them."""
    if clock not in CLOCK_CHOICES:
        raise DeviceError(f"trocar option clock = {clock!r} is not one of {list(CLOCK_CHOICES)}")
    return clock


def interface_stamps(interface: str) -> bool:
    """Whether python-can's ``interface`` gives messages a timestamp of its own."""
    return interface in INTERFACE_CLOCKS
