"""Protocol fakes of the devices, on loopback: start a world with
:class:`~spacecal.testing.fakes.client.WorldProcess` and point the real client libraries at it."""
