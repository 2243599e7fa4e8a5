"""TORCS as a second simulator (issue 15). ``make torcs`` builds TORCS 1.3.7 with our robot
(robot/gvfdrive.cpp) under third_party/torcs; ``protocol.TorcsProcess`` launches a race file written
by ``race.race_xml`` and steps it in lockstep, 0.1 s of simulated time a step. Nothing here is
imported by ``actors.envs``: machines without the build never load it.
"""
