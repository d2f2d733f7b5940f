"""Figures and the HTML report of evaluated runs."""
