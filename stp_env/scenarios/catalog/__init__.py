"""The catalog of named scenarios: one module per scenario (or family), each registering its factories with
:func:`stp_env.scenarios.registry.register`. Every module of this package is imported when a scenario is first
looked up by name (:func:`stp_env.scenarios.registry.names`), so a new scenario is one new file here.

| name | source | vehicles | domain | method | notes |
| --- | --- | --- | --- | --- | --- |
| ``four-vehicle`` | SPP paper Section V, eqs. (28)-(30) | 4 | ``[-1, 1]^2`` | centralized | unit-free toy scale |
| ``city`` | BEACLS Section V, intruder paper Section V-A | 50 | 5 km x 5 km | rtt | synthetic downtown |
| ``city-intruder`` | BEACLS Section VII | 50 | 5 km x 5 km | rtt | ``city``, ``kbar`` 2-4, a departure per 150 s |
| ``bay-area`` | BEACLS Section VI | 200 | 20 km x 15 km | rtt | four cities, no buildings |
| ``tiny`` | ours | 2 | 2 km x 2 km | rtt | two vehicles crossing, 41 x 41 x 40 grid |
| ``tiny-intruder`` | ours | 2 | 2 km x 2 km | rtt | ``tiny`` with ``kbar=2`` |
| ``town`` | ours | 7 | 4 km x 4 km | rtt | the environment's default; two buildings, ``kbar`` 1-4 |
| ``fig6`` | intruder paper Fig. 6 | 4 | 3.6 km x 1.6 km | straight lines | the worst case placed for ``kbar`` 3 |
| ``corridor`` | ours | 20 | 3.6 km x 1.6 km | straight | one trail, spaced by the buffer, ``kbar`` 1-4 |
| ``crossing`` | ours | 20 | 4 km x 4 km | straight | two streams crossing, spaced by the buffer, ``kbar`` 1-4 |
| ``pinwheel`` | ours | 21 | 4 km x 4 km | straight | three streams, waves of three one buffer radius apart |

Scheduled times of arrival. For the city and bay-area studies ``STA_i = sta_spacing * priority`` [s]: the
highest-priority vehicle is due at 0 and each next rank ``sta_spacing`` seconds later, BEACLS's ``t_i^STA = 5 (i -
1)`` with ``i = priority + 1``. (BEACLS Section V-A words the medium- and low-density cases with "the latest
``t_i^STA`` being 0"; that is the same schedule shifted by a constant, which changes nothing for time-invariant
dynamics.)
"""
