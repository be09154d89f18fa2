"""The panel's side of the wire protocol (pure logic over ``bproto``; time passed in as tick milliseconds).

- Boot: one unsolicited HELLO (so the host can tell a reboot); a HELLO request is answered by a HELLO.
- HEARTBEAT out at 2 Hz (uptime_ms, state 0 normal / 1 host lost); any valid host frame keeps the host alive.
- PANEL_STATE in: stored (the panel shows only what the host says) and ACKed; bad values are NACKed.
- PING in: PONG with the device microsecond clock.
- BUTTON out: queued, the head re-sent with the same seq every ``RESEND_MS`` until the host ACKs that seq.
- Host lost after HOST_LOST_MS without a valid host frame: the state is dropped and pending BUTTONs are discarded
  (a press must never act minutes later, when the host comes back).
``write`` is a callable taking bytes (the transport).
"""

import bproto
from panel_clock import ticks_diff

PROTO_MINOR = 0
CAP_LCD_4X20 = 1
CAP_BUTTONS = 2
CAP_LONG_PRESS = 4
HEARTBEAT_MS = 500
HOST_LOST_MS = 1500
RESEND_MS = 200
MAX_PENDING_BUTTONS = 8
HB_NORMAL = 0
HB_HOST_LOST = 1
_HOST_TYPES = (bproto.MSG_HELLO, bproto.MSG_ACK, bproto.MSG_NACK, bproto.MSG_HEARTBEAT, bproto.MSG_PING,
               bproto.MSG_PANEL_STATE)


class PanelLink:
    """Protocol state of the panel. Call ``feed`` with received bytes and ``poll`` regularly (every ~10 ms)."""

    def __init__(self, write, fw_version, uid, now_ms, capabilities=CAP_LCD_4X20 | CAP_BUTTONS | CAP_LONG_PRESS,
                 device_us=None):
        self._write = write
        self.fw_version = fw_version
        self.uid = (bytes(uid) + bytes(12))[:12]
        self.capabilities = capabilities
        self._device_us = device_us
        self._decoder = bproto.Decoder()
        self._seq = 0
        self._boot_ms = now_ms
        self._last_hb_ms = now_ms
        self._uptime_ms = 0  # accumulated (tick values wrap after ~12 days; this does not)
        self._last_poll_ms = now_ms
        self.last_host_ms = None  # tick of the last valid host frame, None before the first
        self.host_lost = False
        self.state = None  # last PANEL_STATE fields (dict) or None
        self.state_count = 0
        self._event_seq = 0
        self._pending = []  # list of [frame_seq, fields]
        self._last_send_ms = None
        self.counters = {"frames_in": 0, "frames_out": 0, "button_sends": 0, "button_acked": 0, "nacks_out": 0,
                         "buttons_dropped": 0, "host_lost": 0}
        self._send(bproto.MSG_HELLO, self._hello_fields())

    # -- sending -----------------------------------------------------------------------------------------------
    def _next_seq(self):
        seq = self._seq
        self._seq = (self._seq + 1) & 0xFFFF
        return seq

    def _send(self, msg_type, fields, seq=None):
        if seq is None:
            seq = self._next_seq()
        self._write(bproto.encode_message(msg_type, seq, fields))
        self.counters["frames_out"] += 1
        return seq

    def _hello_fields(self):
        return {"device_kind": bproto.DEVICE_PANEL, "proto_minor": PROTO_MINOR, "fw_major": self.fw_version[0],
                "fw_minor": self.fw_version[1], "fw_patch": self.fw_version[2], "uid": self.uid,
                "capabilities": self.capabilities}

    def _ack(self, seq):
        self._send(bproto.MSG_ACK, {"acked_seq": seq})

    def _nack(self, seq, code):
        self.counters["nacks_out"] += 1
        self._send(bproto.MSG_NACK, {"acked_seq": seq, "code": code})

    # -- buttons -----------------------------------------------------------------------------------------------
    def queue_button(self, button, action, now_ms):
        """Queue a BUTTON event (sent at once if nothing is pending). Ignored while the host is lost.

        Returns the event_seq, or None when dropped.
        """
        if self.host_lost or self.last_host_ms is None or len(self._pending) >= MAX_PENDING_BUTTONS:
            self.counters["buttons_dropped"] += 1
            return None
        event_seq = self._event_seq
        self._event_seq = (self._event_seq + 1) & 0xFFFF
        self._pending.append([self._next_seq(), {"button": button, "action": action, "event_seq": event_seq}])
        if len(self._pending) == 1:
            self._send_head(now_ms)
        return event_seq

    def _send_head(self, now_ms):
        seq, fields = self._pending[0]
        self._send(bproto.MSG_BUTTON, fields, seq)
        self.counters["button_sends"] += 1
        self._last_send_ms = now_ms

    @property
    def pending_buttons(self):
        """Number of BUTTON events not yet ACKed."""
        return len(self._pending)

    # -- receiving ---------------------------------------------------------------------------------------------
    def feed(self, data, now_ms):
        """Process received bytes (any split); returns the number of valid frames handled."""
        n = 0
        for frame in self._decoder.feed(data):
            n += 1
            self._handle(frame, now_ms)
        return n

    @property
    def decoder_stats(self):
        return self._decoder.stats

    def _handle(self, frame, now_ms):
        self.counters["frames_in"] += 1
        self.last_host_ms = now_ms
        if self.host_lost:
            self.host_lost = False
        t = frame.msg_type
        if t not in _HOST_TYPES:
            self._nack(frame.seq, bproto.NACK_UNKNOWN_TYPE)
            return
        if t == bproto.MSG_HELLO:
            if len(frame.payload) == 0:
                self._send(bproto.MSG_HELLO, self._hello_fields())
            elif bproto.nack_code_for(t, frame.payload):
                self._nack(frame.seq, bproto.NACK_BAD_LENGTH)
            return  # a complete HELLO is a device announcement, not a request: ignore
        try:
            fields = bproto.unpack_payload(t, frame.payload)
        except ValueError:
            if t in (bproto.MSG_PANEL_STATE, bproto.MSG_PING):
                self._nack(frame.seq, bproto.nack_code_for(t, frame.payload) or bproto.NACK_BAD_LENGTH)
            return
        if t == bproto.MSG_PANEL_STATE:
            code = bproto.check_values(t, fields)
            if code:
                self._nack(frame.seq, code)
                return
            self.state = fields
            self.state_count += 1
            self._ack(frame.seq)
        elif t == bproto.MSG_PING:
            dev_us = self._device_us() if self._device_us is not None else now_ms * 1000
            self._send(bproto.MSG_PONG, {"host_time_ns": fields["host_time_ns"], "device_time_us": dev_us})
        elif t == bproto.MSG_ACK:
            if self._pending and self._pending[0][0] == fields["acked_seq"]:
                self._pending.pop(0)
                self.counters["button_acked"] += 1
                if self._pending:
                    self._send_head(now_ms)
        elif t == bproto.MSG_NACK and self._pending and self._pending[0][0] == fields["acked_seq"]:
            self._pending.pop(0)  # the host refused it: do not insist
            if self._pending:
                self._send_head(now_ms)
        # HEARTBEAT: only keeps the host alive (done above)

    # -- timers ------------------------------------------------------------------------------------------------
    def poll(self, now_ms):
        """Timers: host-lost detection, heartbeat out, BUTTON re-send. Call every few milliseconds."""
        self._uptime_ms += ticks_diff(now_ms, self._last_poll_ms)
        self._last_poll_ms = now_ms
        since = self.last_host_ms if self.last_host_ms is not None else self._boot_ms
        if not self.host_lost and ticks_diff(now_ms, since) >= HOST_LOST_MS:
            self.host_lost = True
            self.counters["host_lost"] += 1
            self.state = None
            self.counters["buttons_dropped"] += len(self._pending)
            self._pending = []
        if ticks_diff(now_ms, self._last_hb_ms) >= HEARTBEAT_MS:
            self._last_hb_ms = now_ms
            self._send(bproto.MSG_HEARTBEAT, {"uptime_ms": self._uptime_ms & 0xFFFFFFFF,
                                              "state": HB_HOST_LOST if self.host_lost else HB_NORMAL})
        if self._pending and ticks_diff(now_ms, self._last_send_ms) >= RESEND_MS:
            self._send_head(now_ms)

    def host_silent_ms(self, now_ms):
        """Milliseconds since the last valid host frame (since boot if none yet)."""
        since = self.last_host_ms if self.last_host_ms is not None else self._boot_ms
        return ticks_diff(now_ms, since)
