"""The host PC: motion capture in, the exported policy at 1 Hz, speed commands out to the
Pi agent; field trials with crash-safe logs; and the digital twin that runs it all
against the simulator and the emulated firmware."""
