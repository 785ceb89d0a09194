"""Protocol emulators of the sonar devices (SRF08 I2C bus); the Roboteq emulator lives in hw.roboteq."""
