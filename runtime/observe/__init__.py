"""What a run shows: its report and summary, the live line and the live view's signals."""
