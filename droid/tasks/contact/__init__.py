"""Force-controlled contact tasks (issue 27 item 5; thesis §7.3): droid.tasks.contact.core."""
