"""Joint velocities and accelerations from sampled joint positions (and velocities).

- :mod:`.fit`: the local polynomial fit on irregular stamps, shared by every estimator;
- :mod:`.batch`: whole recordings (looks both ways in time);
- :mod:`.stream`: one joint-state message at a time, for the node.
"""
