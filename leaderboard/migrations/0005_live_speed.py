# Issue 48: live speed control on race day, an event setting (off by default).

from django.db import migrations, models


class Migration(migrations.Migration):

    dependencies = [
        ('leaderboard', '0004_event_conditions'),
    ]

    operations = [
        migrations.AddField(
            model_name='event',
            name='live_speed_control',
            field=models.BooleanField(
                default=False,
                help_text="During their race-day turn, a racer sets their car's speed "
                "(0.5×-1.5×) from their phone.",
            ),
        ),
    ]
