"""Force-sensing trocars."""

from vbfe.drivers.trocar.base import ForceSensor

__all__ = ["ForceSensor"]
