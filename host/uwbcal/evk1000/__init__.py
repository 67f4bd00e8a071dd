"""The emulated EVK1000: peripheral models and the tools that drive them (otgfs.py: the USB
OTG FS core; usbhost.py: a USB host that enumerates it as Linux does; usbbridge.py: its bulk
endpoints as a pty, like /dev/ttyACM0; usbhosted.py: the USB driver built for the host)."""
