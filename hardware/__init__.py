"""Driving and recording COBRA through dynamixel-sdk, and a servo-bus emulator."""
