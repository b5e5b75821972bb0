"""Controllers for the N-zone bed and their classical design rules."""

from ._base import AbstractController as AbstractController
