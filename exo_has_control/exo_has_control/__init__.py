"""Hip/knee PD controllers and the gait trajectory publisher (issue 4 fills it)."""
