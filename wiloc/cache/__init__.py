"""The descriptor cache: its entries on disk, journals of runs in progress, locks."""
