"""What drives the robot: scripted gaits, the hand-written ``goto`` controller, and
exported policies on onnxruntime with their feature layer; ``drivers`` names one of
them for an evaluation. Control reads the world's observation
(:mod:`tumblebot.sim.observation`) and its tasks, never the other way round.
"""
