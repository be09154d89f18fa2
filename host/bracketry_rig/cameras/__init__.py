"""GigE cameras through Aravis 0.8 (PyGObject): profiles, streaming, pixel unpacking and an in-process fake camera.

Modules:
    pixels      PFNC pixel-format codes and vectorised unpacking (BayerRG12p -> uint16), no Aravis needed.
    frame_ids   16-bit GVSP frame-id unwrapping.
    aravis_gi   the one place that imports Aravis (clear error when the typelib or PyGObject is missing).
    profiles    camera kinds (``basler_ace2``, ``aravis_fake``): features written and read back.
    camera      open by IP or device id, configure, stream in our own thread, stream statistics.
    fake        a fake GigE camera server (in-process ``Aravis.GvFakeCamera``) serving given pixels.
    netns       run a command inside a private network namespace with extra loopback addresses.
"""
