"""From a design to a robot on the bench: the servo catalogue and the fabrication package.

:mod:`.catalogue` holds the servos; :mod:`.layout` turns a design, the mass model and a
servo into the parts' dimensions (millimetres); :mod:`.cutfiles` writes the laser-cutter
files, :mod:`.cad` the 3D assembly (``build123d``, the ``build`` extra) and
:mod:`.package` the whole package with its parts list and assembly guide.
"""
