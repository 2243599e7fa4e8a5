"""TORCS as a second simulator (issue 15). ``make torcs`` builds TORCS 1.3.7 with our robot
(robot/gvfdrive.cpp) under third_party/torcs; ``protocol.TorcsProcess`` launches a race file written
by ``race.race_xml`` and steps it in lockstep, 0.1 s of simulated time a step. ``env`` is
``TorcsDrive-v0`` (LaneDrive's contract; ``sim`` is its core), ``geometry`` reads a road's XML into a
centreline, ``road_map`` draws it for LaneDrive's camera, ``roads`` is the train/test road set.
``actors.envs`` registers ``TorcsDrive-v0`` by name only: machines without the build never load this.
"""
