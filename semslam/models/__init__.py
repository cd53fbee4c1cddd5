"""The CAD / structure model library: what front-ends recognise and the simulator places.

``cad``: the object classes of the tank (valves, elbows, tees, sockets) as meshes with their ports.
``structures``: subsea structures for the sonar (manifold, PLET, wellhead) with their hubs.
Both are used alike by the simulator (``semslam.sim``) and by the front-ends, which must never
import the simulator.
"""
