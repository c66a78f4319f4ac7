"""AgileX LIMO serial bridge: framing, kinematics, bridge core, serial link, chassis emulator, node."""
