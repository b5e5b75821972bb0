"""3D-printer firmware: Klipper's log as records, and controller settings in the firmware's own
units and syntax (Klipper, Marlin, Kalico), each law re-derived from that firmware's source."""
