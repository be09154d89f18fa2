# ruff: noqa: UP031  (MicroPython firmware: %-formatting is the cheapest, most portable formatting on the board)
"""4x20 screen layouts of the status panel, rendered into a character buffer (a list of 4 strings of 20 chars).

Pure logic: runs unchanged under MicroPython (board, WebAssembly runtime) and CPython. The status screen::

    L:REC R:REC TRIG:REC     cameras left/right, trigger
    IM:CAL LI:REC GN:ERR     IMU, lidar, GNSS
    21.9/21.9 931G 12:34     fps left/right (1 decimal), free disk, recording time
    <host message, 20 ch>    the host's message line

States are OFF, IDL(E), REC, ERR, CAL; ERR blinks (shown / blanked every 500 ms). Free disk: ``9.5G`` below 10 GB,
``931G`` below 1000 GB, ``1.2T`` above (decimal units, from megabytes). Recording time: ``MM:SS`` below 100 min,
``HhMMm`` below 10 h, ``NNNh`` above; ``--:--`` when nothing records and the time is 0.
"""

WIDTH = 20
HEIGHT = 4

STATE_OFF = 0
STATE_IDLE = 1
STATE_REC = 2
STATE_ERR = 3
STATE_CAL = 4
STATE_TEXT = ("OFF", "IDL", "REC", "ERR", "CAL")
BLANK_STATE = "   "
SENSOR_FIELDS = ("cam_left", "cam_right", "trigger", "imu", "lidar", "gnss")
BLINK_PERIOD_MS = 1000


def fit(text):
    """``text`` made printable ASCII and padded/truncated to exactly WIDTH characters."""
    out = []
    for ch in text:
        o = ord(ch)
        out.append(ch if 32 <= o < 127 else "?")
    s = "".join(out)[:WIDTH]
    return s + " " * (WIDTH - len(s))


def message_text(message):
    """The host's message (bytes or str, space padded) as a str; non-printable bytes become '?'."""
    if isinstance(message, (bytes, bytearray)):
        chars = []
        for b in message:
            chars.append(chr(b) if 32 <= b < 127 else ("" if b == 0 else "?"))
        return "".join(chars)
    return str(message)


def state_text(state, blink_on):
    """3-char text of a sensor state code (0..4); ERR is blanked when ``blink_on`` is False; unknown -> '???'."""
    if state == STATE_ERR and not blink_on:
        return BLANK_STATE
    if 0 <= state < len(STATE_TEXT):
        return STATE_TEXT[state]
    return "???"


def fps_text(fps_centi):
    """4-char frame rate from hundredths of fps: 2190 -> '21.9', 550 -> ' 5.5', 12000 -> ' 120'."""
    tenths = (int(fps_centi) + 5) // 10
    if tenths >= 1000:
        return "%4d" % min(tenths // 10, 9999)
    return "%2d.%d" % (tenths // 10, tenths % 10)


def disk_text(free_disk_mb):
    """4-char free disk space from megabytes (decimal GB/TB): '9.5G', '931G', '1.2T', '12T'."""
    mb = int(free_disk_mb)
    if mb < 9950:
        tenths = (mb + 50) // 100
        return "%d.%dG" % (tenths // 10, tenths % 10)
    gb = (mb + 500) // 1000
    if gb < 1000:
        return "%3dG" % gb
    tenths_tb = (mb + 50000) // 100000
    if tenths_tb < 100:
        return "%d.%dT" % (tenths_tb // 10, tenths_tb % 10)
    return "%3dT" % min((mb + 500000) // 1000000, 999)


def rec_text(rec_seconds, recording):
    """5-char recording time: '12:34' (< 100 min), '1h05m' (< 10 h), ' 123h'; '--:--' when idle at 0 s."""
    s = int(rec_seconds)
    if s <= 0 and not recording:
        return "--:--"
    if s < 6000:
        return "%02d:%02d" % (s // 60, s % 60)
    if s < 36000:
        return "%dh%02dm" % (s // 3600, (s % 3600) // 60)
    return "%4dh" % min(s // 3600, 9999)


def blink_phase(now_ms):
    """True during the 'on' half of the ERR blink period."""
    return (now_ms % BLINK_PERIOD_MS) < (BLINK_PERIOD_MS // 2)


def render_status(st, blink_on):
    """The status screen from a PANEL_STATE field dict ``st`` -> list of HEIGHT strings of WIDTH chars."""
    def s(name):
        return state_text(st.get(name, 0), blink_on)

    recording = False
    for name in SENSOR_FIELDS:
        if st.get(name, 0) == STATE_REC:
            recording = True
    line0 = "L:%s R:%s TRIG:%s" % (s("cam_left"), s("cam_right"), s("trigger"))
    line1 = "IM:%s LI:%s GN:%s" % (s("imu"), s("lidar"), s("gnss"))
    line2 = "%s/%s %s %s" % (fps_text(st.get("fps_left_centi", 0)), fps_text(st.get("fps_right_centi", 0)),
                             disk_text(st.get("free_disk_mb", 0)), rec_text(st.get("rec_seconds", 0), recording))
    line3 = message_text(st.get("message", b""))
    return [fit(line0), fit(line1), fit(line2), fit(line3)]


def version_text(version):
    """'1.2.3' from a (major, minor, patch) tuple."""
    return "%d.%d.%d" % (version[0], version[1], version[2])


def uid_text(uid):
    """Hex of the first 6 bytes of the device UID (the ESP32 MAC)."""
    return "".join(["%02X" % b for b in bytes(uid)[:6]])


def render_boot(version, uid):
    """Boot screen: firmware version, device id, waiting for the host."""
    return [fit("bracketry panel"), fit("fw " + version_text(version)), fit("id " + uid_text(uid)),
            fit("waiting for host...")]


def render_host_lost(lost_for_ms, version, blink_on):
    """HOST LOST screen: blinking title, seconds since the last host frame, a hint, the firmware version."""
    secs = lost_for_ms // 1000
    if secs > 99999:
        secs = 99999
    title = "***  HOST LOST  ***" if blink_on else "     HOST LOST"
    return [fit(title), fit("no host for %d s" % secs), fit("check USB / daemon"), fit("fw " + version_text(version))]
