"""The host link: frames (framing.py), byte transports (transport.py), request/response and
streams (client.py). The wire format itself is generated into proto_gen.py from protocol/."""
