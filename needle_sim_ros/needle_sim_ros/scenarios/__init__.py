"""Command-line scenarios of the needle model (``needle_scenario``, see ``cli``)."""
