"""Hip/knee PD controllers and the gait trajectory publisher (trajectory generation so far)."""
