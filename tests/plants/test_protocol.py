"""The device protocol: packets round-trip bit for bit, every malformed one is refused with its
reason, and the UDP device takes only newer samples from its peer (a fake device on loopback)."""

import socket
import time
from typing import TypeVar

import numpy as np
import pytest

from manus.plants import protocol as P
from manus.plants.device import DeviceError, UdpDevice, open_device

_Packet = TypeVar("_Packet", P.Sensor, P.Command, P.Info, P.Header)


def _decode(kind: type[_Packet], data: bytes) -> _Packet:
    """The packet `data` holds, of the kind the test sent."""
    packet = P.decode(data)
    assert isinstance(packet, kind)
    return packet


def test_packets_round_trip_exactly():
    counts = np.array([-7, 2**31 - 1, 123456], np.int32)
    s = _decode(P.Sensor, P.encode_sensor(41, 123_456_789_012, counts, P.STATUS_LATE | P.STATUS_SATURATED))
    assert (s.seq, s.time_ns, s.flags) == (41, 123_456_789_012, P.STATUS_LATE | P.STATUS_SATURATED)
    assert s.counts.tolist() == counts.tolist()
    c = _decode(P.Command, P.encode_command(7, 99, 41, [1.5, -0.25], P.CMD_VOLTS))
    assert (c.seq, c.time_ns, c.ack, c.flags) == (7, 99, 41, P.CMD_VOLTS)
    assert c.values.tolist() == [1.5, -0.25]  # exact in float32
    info = P.Info(2, 1000.0, 131072.0, 2.22, 10.0)
    assert P.decode(P.encode_info(0, 5, info)) == info
    assert info.torque_limit == pytest.approx(22.2)
    h = _decode(P.Header, P.encode_hello(3, 8, 1))
    assert (h.kind, h.seq, h.time_ns) == (P.HELLO, 3, 8)
    # documented sizes: 20-byte header, 4-byte CRC
    assert [P.size(k, 2) for k in (P.SENSOR, P.COMMAND, P.HELLO, P.INFO)] == [32, 36, 24, 56]
    assert len(P.encode_sensor(1, 0, [0, 0])) == 32


def _reason(data):
    with pytest.raises(P.ProtocolError) as e:
        P.decode(data)
    return e.value.reason


def test_malformed_packets_are_refused_with_their_reason():
    good = P.encode_sensor(5, 10, [1, 2])
    assert _reason(good[:-1]) == "length"
    assert _reason(good + b"\0") == "length"
    assert _reason(b"\x01\x02") == "length"
    assert _reason(b"XX" + good[2:]) == "magic"
    assert _reason(good[:2] + bytes([P.VERSION + 1]) + good[3:]) == "version"
    assert _reason(good[:3] + bytes([9]) + good[4:]) == "kind"
    assert _reason(good[:4] + bytes([0]) + good[5:]) == "joints"
    # every single flipped bit of the payload or the counters is caught
    for i in range(6, len(good)):
        for bit in (0, 7):
            bad = bytearray(good)
            bad[i] ^= 1 << bit
            assert _reason(bytes(bad)) == "crc", (i, bit)


def test_sequence_order_wraps_around():
    assert P.newer(1, None) and P.newer(6, 5) and not P.newer(5, 5) and not P.newer(4, 5)
    assert P.newer(0, 2**32 - 1) and P.newer(3, 2**32 - 2)
    assert not P.newer(2**32 - 1, 0)


def test_device_urls_are_checked():
    for url, words in [
        ("tcp://127.0.0.1:5", "unknown transport"),
        ("udp://127.0.0.1", "expected udp://HOST:PORT"),
        ("127.0.0.1:5", "unknown transport"),
        ("udp://:5", "expected udp://HOST:PORT"),
    ]:
        with pytest.raises(DeviceError, match=words):
            open_device(url)


def test_a_dead_link_is_one_clear_error():
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]  # bound but never answers
        dev = open_device(f"udp://127.0.0.1:{port}")
        with pytest.raises(DeviceError, match=f"udp://127.0.0.1:{port}: no answer from the device within 0.2 s"):
            dev.connect(timeout=0.2)
        dev.close()


@pytest.fixture
def fake_device():
    """A socket playing the device: it answers the HELLO with INFO, the test drives the rest."""
    dev_sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    dev_sock.bind(("127.0.0.1", 0))
    dev_sock.settimeout(2.0)
    host = UdpDevice("127.0.0.1", dev_sock.getsockname()[1])
    info = P.Info(2, 1000.0, 131072.0, 2.22, 10.0)
    import threading

    def answer():
        data, addr = dev_sock.recvfrom(2048)
        assert P.header(data).kind == P.HELLO
        dev_sock.sendto(P.encode_info(0, 0, info), addr)

    t = threading.Thread(target=answer)
    t.start()
    assert host.connect(timeout=2.0) == info
    t.join()
    yield dev_sock, host
    host.close()
    dev_sock.close()


def test_udp_device_takes_only_newer_samples_from_its_peer(fake_device):
    dev_sock, host = fake_device
    peer = host.address
    stranger = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    stranger.bind(("127.0.0.1", 0))
    stranger.sendto(P.encode_sensor(100, 0, [9, 9]), peer)  # valid, but from another address
    dev_sock.sendto(P.encode_sensor(1, 11, [1, 2]), peer)
    dev_sock.sendto(P.encode_sensor(3, 13, [3, 4]), peer)
    dev_sock.sendto(P.encode_sensor(2, 12, [5, 6]), peer)  # out of order: older than 3
    dev_sock.sendto(P.encode_sensor(3, 13, [3, 4]), peer)  # repeated
    dev_sock.sendto(b"garbage!" * 4, peer)  # 32 bytes: the size of a sensor packet, not one
    dev_sock.sendto(P.encode_sensor(4, 14, [1, 2, 3]), peer)  # 3 joints where the device has 2
    dev_sock.sendto(P.encode_command(1, 0, 0, [0.0, 0.0]), peer)  # a command: wrong direction
    dev_sock.sendto(P.encode_sensor(5, 15, [7, 8]), peer)
    time.sleep(0.05)
    got = []
    while (s := host.receive(time.perf_counter_ns() + 20_000_000)) is not None:
        got.append((s.seq, s.counts.tolist()))
    assert got == [(1, [1, 2]), (3, [3, 4]), (5, [7, 8])]
    assert dict(host.refused) == {"address": 1, "order": 2, "magic": 1, "joints": 1, "kind": 1}
    # the command answering sample 5 reaches the device intact
    host.send(5, [0.5, -1.0], P.CMD_VOLTS)
    cmd = _decode(P.Command, dev_sock.recvfrom(2048)[0])
    assert (cmd.ack, cmd.flags, cmd.values.tolist()) == (5, P.CMD_VOLTS, [0.5, -1.0])
    host.stop()
    stops = [_decode(P.Command, dev_sock.recvfrom(2048)[0]) for _ in range(3)]
    assert all(c.flags & P.CMD_STOP and not np.any(c.values) for c in stops)
    stranger.close()
