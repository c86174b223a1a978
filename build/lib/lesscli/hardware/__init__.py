"""Hardware: Dynamixel Protocol 2.0 codec, a servo bus over ``dynamixel_sdk``, the scissor lift, and a
pseudo-terminal servo emulator so every command can be tried (and tested) without a lift.

Importing this package loads neither ``dynamixel_sdk`` nor ``serial``; the bus imports them when opened.
"""
