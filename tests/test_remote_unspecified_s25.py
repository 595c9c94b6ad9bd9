"""``s2a-capture remote 0.0.0.0`` (a phone app simulated on this machine, listening on all addresses): the
commands reach this machine, whose replies come from 127.0.0.1. Since replies are taken only from the
phone's address, they were all ignored and every command timed out ("1 datagram(s) from 127.0.0.1:...
not the phone's address")."""

from __future__ import annotations

from test_osc_remote import FakePhone

from capture.osc_remote import PhoneRemote


def test_a_phone_addressed_as_this_machines_unspecified_address_is_heard():
    phone = FakePhone(host="0.0.0.0", battery=0.5)
    try:
        with PhoneRemote("0.0.0.0", phone.port, timeout_s=10) as remote:
            assert remote.battery() == 0.5
            assert remote.stranger_datagrams == 0
    finally:
        phone.close()
