"""The Raspberry Pi agent: authenticated UDP from the host in, framed serial to the
Arduino out. Needs pyserial and the standard library only (``pip install tumblebot[agent]``).
"""
